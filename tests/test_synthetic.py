"""plant.emulate_log: the library's own emulator of the logged P experiment."""
import dataclasses

import numpy as np
import pytest

import plant


def test_emulated_log_reproduces_the_development_log(paper_log, truth):
    """The core with the true f reproduces the paper log sample for sample."""
    f = np.array(truth(paper_log.name)["f_vector"])
    em = plant.emulate_log(paper_log, f)
    np.testing.assert_array_equal(em.e_pulses, paper_log.e_pulses)
    np.testing.assert_allclose(em.q_ref, paper_log.q_ref, atol=1e-12)


def test_emulated_log_at_other_settings_round_trips(paper_log, truth, tmp_path):
    f = np.array(truth(paper_log.name)["f_vector"])
    rig = dataclasses.replace(paper_log.rig, encoder_ppr=(250, 250), p_gain_A_per_pulse=(0.3, 0.3))
    em = plant.emulate_log(paper_log, f, rig=rig, duration_s=1.0, name="coarse",
                           current_noise_A=0.05, rng=1)
    assert em.n_samples == round(1.0 / rig.sample_time_s) + 1
    assert not np.allclose(em.i_A, 0.3 * em.e_pulses)  # noisy logged currents
    em = em.replace(path=tmp_path / "coarse.csv")
    em.save(em.path)
    back = plant.load_log(tmp_path / "coarse.csv")
    assert back == em and back.rig.encoder_ppr == (250, 250)
    assert plant.output_error(back, f) == 0.0  # a known answer: the emulating f


def test_emulated_flexible_log_differs_from_rigid(paper_log, truth):
    f = np.array(truth(paper_log.name)["f_vector"])
    flex = plant.FlexibleJoints((8000.0, 4000.0), (2.0, 1.0), 200e-6)
    em = plant.emulate_log(paper_log, f, flexible=flex, duration_s=0.5)
    rigid = plant.emulate_log(paper_log, f, duration_s=0.5)
    assert np.any(em.e_pulses != rigid.e_pulses)
    with pytest.raises(ValueError, match="duration_s"):
        plant.emulate_log(paper_log, f, duration_s=-1.0)

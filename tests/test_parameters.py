"""Parameterisations: the x -> f maps that identify() searches, built in and user-written."""
import numpy as np
import pytest

import identification as idf
import plant
from identification.parameters import (
    BaseParameters,
    ConsistentBaseParameters,
    Parameterisation,
    PayloadParameters,
)


class GravityOnly(Parameterisation):
    """A user's own parameterisation: only the gravity terms f5, f6, f8, f9 are unknown."""

    name = "gravity-only"

    def __init__(self, f_known):
        self.f_known = np.asarray(f_known, dtype=float)

    def names(self, log):
        return ["f5", "f6", "f8", "f9"]

    def bounds(self, log):
        return log.rig.bounds[[4, 5, 7, 8]]

    def to_f(self, x, log):
        x = np.asarray(x, dtype=float)
        f = np.broadcast_to(self.f_known, x.shape[:-1] + (9,)).copy()
        f[..., [4, 5, 7, 8]] = x
        return f


@pytest.fixture(scope="module")
def own_log(paper_log, truth):
    """A 1 s log emulated with the true f: a known answer."""
    f = np.array(truth(paper_log.name)["f_vector"])
    return plant.emulate_log(paper_log, f, duration_s=1.5, name="own"), f


def test_a_user_written_parameterisation_recovers_its_parameters(own_log):
    log, f = own_log
    known = f.copy()
    res = idf.identify(log, parameters=GravityOnly(known), rng=1, progress=False,
                       ga_options={"n_gen": 8}, refine_options={"n_starts": 2})
    assert res.parameters == "gravity-only" and res.x_names == ["f5", "f6", "f8", "f9"]
    assert res.x.shape == (4,) and res.f.shape == (9,)
    np.testing.assert_allclose(res.f[[0, 1, 2, 3, 6]], f[[0, 1, 2, 3, 6]])  # held fixed
    rel = np.abs(res.f - f) / np.abs(f)
    assert rel[5] < 1e-3 and rel[8] < 1e-3, rel  # f6, f9: well excited
    assert res.fun <= plant.output_error(log, res.f, substeps=1) + 1e-9


def test_built_in_maps(paper_log):
    a3 = paper_log.rig.a3_m
    x7 = np.array([0.9, 0.35, 0.03, -0.9, 4.5, -0.1, 3.8])
    f = ConsistentBaseParameters().to_f(x7, paper_log)
    assert f[2] == pytest.approx(a3 * 0.03) and f[3] == pytest.approx(a3 * -0.9)
    np.testing.assert_array_equal(f[[0, 1, 4, 5, 6, 7, 8]], x7)
    assert ConsistentBaseParameters().bounds(paper_log).shape == (7, 2)
    fb = np.arange(1.0, 10.0)
    np.testing.assert_array_equal(BaseParameters().to_f(fb, paper_log), fb)
    prior = np.array([0.9, 0.35, 0.01, -0.4, 0.03, -0.9, 4.5, -0.1, 3.8])
    pay = PayloadParameters(prior)
    np.testing.assert_allclose(pay.to_f(np.zeros(4), paper_log), prior)  # no payload
    f_loaded = pay.to_f(np.array([2.0, 0.1, 0.0, 0.0]), paper_log)
    expected = plant.add_payload(prior, plant.Payload(2.0, (0.1, 0.0)), a3)
    np.testing.assert_allclose(f_loaded, expected, rtol=1e-12, atol=1e-12)


def test_parameters_and_shorthands_do_not_mix(paper_log):
    with pytest.raises(ValueError, match="not both"):
        idf.identify(paper_log, parameters=BaseParameters(), consistent=True)
    with pytest.raises(ValueError, match="Parameterisation"):
        idf.identify(paper_log, parameters="base")
    with pytest.raises(ValueError, match="prior"):
        idf.identify(paper_log, payload=True)
    with pytest.raises(ValueError, match="shape"):
        BaseParameters(bounds=np.zeros((3, 2)))

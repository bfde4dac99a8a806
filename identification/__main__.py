"""``python -m identification``: see :mod:`identification.cli`."""
import sys

from identification.cli import main

if __name__ == "__main__":
    sys.exit(main())

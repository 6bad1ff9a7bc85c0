"""`python -m jaxnat.train` (the same as `jaxnat train`): see `jaxnat.training`."""

import sys

from jaxnat.training import *  # noqa: F401,F403  (the public API, as `jaxnat.train.train` etc.)
from jaxnat.training import __all__, main  # noqa: F401

if __name__ == "__main__":
    sys.exit(main())

"""`python -m jaxnat.reproduce`: the same as `jaxnat reproduce`."""

import sys

from jaxnat.reproduce.command import main

sys.exit(main())

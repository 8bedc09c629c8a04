"""`python -m jaxmr._cli`: the `jaxmr` program."""

import sys

from . import main

sys.exit(main())

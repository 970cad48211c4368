"""`python -m monte ...` runs the `monte` command."""

import sys

from .cli import main

sys.exit(main())

"""`python -m monte ...` runs the `monte` command."""

from .cli import run

run()

"""`python -m ovis.services.cli` runs the `ovis` command."""

from ovis.services.cli import main

main()

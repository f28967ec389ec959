"""`python -m drivetrain ...` is the `drivetrain` command."""
from drivetrain.cli import main

raise SystemExit(main())

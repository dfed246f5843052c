"""`python -m pipeline.cli`: the `render` command."""
import sys

from .entry import main

sys.exit(main())

"""``python -m harness`` is the ``motiontwin`` console script."""
import sys

from harness.cli import main

sys.exit(main())

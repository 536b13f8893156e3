"""``python -m motiontwin`` is the ``motiontwin`` console script."""
import sys

from motiontwin.cli import main

sys.exit(main())

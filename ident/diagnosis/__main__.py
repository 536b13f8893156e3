"""``python -m motiontwin.ident.diagnosis BUNDLE --out OUT``."""
import sys

from motiontwin.ident.diagnosis import main

sys.exit(main())

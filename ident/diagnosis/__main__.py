"""``python -m ident.diagnosis BUNDLE --out OUT``."""
import sys

from ident.diagnosis import main

sys.exit(main())

"""``python -m basestation.sim``: the simulated robot as its own process (see process.py)."""

import sys

from basestation.sim.process import main

sys.exit(main())

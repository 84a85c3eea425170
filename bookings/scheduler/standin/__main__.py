"""``python -m bookings.scheduler.standin``: serve the stand-in broker."""

import sys

from bookings.scheduler.standin.broker import main

sys.exit(main())

"""``python -m sim_devices``: the simulated lab as a standalone process (see ``sim_devices.cli``)."""

import sys

from .cli import main

sys.exit(main())

"""``python -m selfillum.cli``."""

import sys

from selfillum.cli.main import main

sys.exit(main())

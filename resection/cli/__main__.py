"""``python -m resection.cli``."""

import sys

from resection.cli.main import main

sys.exit(main())

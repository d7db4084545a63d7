"""``python -m neuenh_service.cli.client``: the same as the ``neuenh-client`` script."""

import sys

from . import main

sys.exit(main())

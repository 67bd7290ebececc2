"""``python -m fruitnerfpp_ros`` runs the ``fruitnerfpp`` command line."""

import sys

from fruitnerfpp_ros.cli.main import main

sys.exit(main())

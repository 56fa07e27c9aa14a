"""``python -m lowcam.cli``: the ``lowcam`` command line."""
import sys

from . import main

sys.exit(main())

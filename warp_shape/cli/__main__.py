"""``python -m warp_shape.cli``: the ``warp-shape`` command."""

import sys

from . import main

sys.exit(main())

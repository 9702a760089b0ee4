"""``python -m srde_fusion.cli``: the ``srde-fusion`` command without the console script."""

import sys

from .main import main

sys.exit(main())

"""``python -m glraster``: the glraster command (as ``python -m glraster.cli``)."""

import sys

from glraster.cli import main

sys.exit(main())

"""``python -m glraster.cli``: the glraster command."""

import sys

from glraster.cli import main

sys.exit(main())

"""``python -m ilcsan.cli``: the same as the ``ilcsan`` command."""

import sys

from . import main

sys.exit(main())

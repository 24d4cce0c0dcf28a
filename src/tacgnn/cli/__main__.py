"""``python -m tacgnn.cli``: the `tacgnn` command (as torchrun launches it)."""

import sys

from tacgnn.cli import main

sys.exit(main())

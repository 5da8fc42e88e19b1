"""``python -m doabench``: the same as the ``doabench`` command."""
import sys

from doabench.cli.main import main

sys.exit(main())

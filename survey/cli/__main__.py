"""``python -m survey.cli``: the same as the ``tunnelsim`` command."""

import sys

from survey.cli.main import main

sys.exit(main())

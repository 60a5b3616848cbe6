"""`python -m graphsvc.cli`: the `graphsvc` command."""

import sys

from graphsvc.cli import main

sys.exit(main())

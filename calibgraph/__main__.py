import sys

from calibgraph.cli.main import main

sys.exit(main())

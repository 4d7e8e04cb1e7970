import sys

from dgcal.cli import main

sys.exit(main())

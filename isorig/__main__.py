import sys

from isorig.cli import main

sys.exit(main())

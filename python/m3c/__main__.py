import sys

from m3c.cli import main

sys.exit(main())

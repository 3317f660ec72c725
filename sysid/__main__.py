import sys

from sysid.cli import main

sys.exit(main())

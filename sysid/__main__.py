import sys

from sysid.cli import main

try:
    status = main()
except KeyboardInterrupt:  # arrived after main() returned: the command's work is done
    status = 130
sys.exit(status)

import sys

from skyrecon.cli.entry import main

sys.exit(main())

import sys

from skyrecon.cli.main import main

sys.exit(main())

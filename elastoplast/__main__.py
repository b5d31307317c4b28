import sys

from elastoplast.cli.main import main

sys.exit(main())

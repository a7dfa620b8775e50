import sys

from ballchain.cli import main

sys.exit(main())

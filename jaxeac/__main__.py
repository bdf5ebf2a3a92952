import sys

from jaxeac.cli import main

sys.exit(main())

import sys

from trq_offboard.daemon import main

sys.exit(main())

import sys

from sil_vehicle.daemon import main

sys.exit(main())

import sys

from pipeline_sim.cli import main

sys.exit(main())

"""The study at many airspeeds on Dask (same as ``sysid batch``).

Runs the full identification chain at 0, 20, 40, 60, 80 and 100 kt (or the conditions of a
speeds TOML) as independent tasks on a local Dask cluster of processes, or on an existing
scheduler, and writes reports/batch/: batch.nc (every result on a ``condition`` dimension),
batch_derivatives.png (each derivative against airspeed with Cramer-Rao bars and the truth
linearisation), batch_summary.txt and, with several seeds per speed, the Monte Carlo summary.
A failing condition is reported and the others complete; re-running resumes.

    python workflows/sweep_speeds.py [speeds.toml] [--scheduler tcp://host:port]
                                     [--workers N] [--quick] [--quiet] [-o DIR]
"""

import sys

from sysid.cli import main

if __name__ == "__main__":
    sys.exit(main(["batch", *sys.argv[1:]]))

"""The paper's hover study end to end (same as ``sysid run hover``).

Build the truth FMU, trim, fly the campaign (sweeps, 3211, 2311), compute conditioned
composite frequency responses, identify the 6-DoF model in the frequency domain (with model
reduction) and in the time domain, verify both on 2311 data, compare them with the truth
linearisation, export both as FMUs and validate them against the truth FMU, and write the
report. Everything lands in reports/hover/.

    python workflows/hover.py [--quiet]
"""

import sys

from sysid.pipeline.study import StudySettings, run_study

if __name__ == "__main__":
    report = run_study("reports/hover", StudySettings(airspeed_kt=0.0, structure="hover_6dof"),
                       quiet="--quiet" in sys.argv[1:])
    print(report.resolve())

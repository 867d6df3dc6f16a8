"""The names of fmcwlog's trajectories, apart from the code that makes them.

Evaluation and the output writers need the names only; importing them from here keeps
scikit-learn and the rest of the estimation stack out of ``fmcwlog report`` (1.7 s of
imports). :mod:`fmcwlog.frontend.methods` builds its classes on these names, and a test
checks that the two agree.
"""

IMPROVED = "improved"
BASELINE = "baseline"
WHEEL_ODOMETRY = "wheel_odometry"  # the motion prior's own trajectory, written beside the methods'

METHOD_NAMES = (IMPROVED, BASELINE)  # the methods: each builds a map
SEGMENTING_METHODS = (IMPROVED,)  # the methods that judge points moving or static

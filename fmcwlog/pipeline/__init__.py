"""One log processed, from its file to its output folder (``fmcwlog process``, ``fmcwlog calibrate``).

- ``params``          every parameter of a run: the front end's and the back end's, config files
- ``options``         what a run does: methods, topics, parameters, back end; their digest
- ``runner``          the loop over a log's inputs, the methods side by side, with the motion prior
- ``process``         the recipe: log -> runner -> outputs and back ends -> ``run.json``
- ``run_record``      ``run.json`` as a typed record
- ``method_process``  the costliest method in a child process
- ``children``        child processes that end with their parent
- ``calibrate``       the mount and the wheels estimated from the log itself
"""

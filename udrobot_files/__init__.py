"""File-system rules shared by ``identification`` and ``udrobot_ctrl``: the output policy and private caches.

Both packages write files and compile code; this small package holds the one definition of how (it imports
only the standard library and, lazily, numba's configuration), so that neither package imports the other to
get it. The dependency direction of the project is

    udrobot_files  <-  identification  <-  udrobot_ctrl

(arrows point from what uses to what is used): ``identification`` turns test data into coefficient sets and
never imports ``udrobot_ctrl``; ``udrobot_ctrl`` (vehicle models, plant, control, diagnosis) consumes them.

Modules
-------
output : output-file policy (never destroy an input, never overwrite without ``--force``, atomic writes, one
    check per command)
locks : exclusive locks between runs (output claims, sensitivity study folders)
inputs : reading a file an input names (a regular file of bounded size, never a pipe or a device)
caches : private on-disk folders for compiled code (numba, casadi-generated C)
nesting : JSON/TOML documents nested too deeply to parse: one error naming the file, never a RecursionError
exports : lazy re-exports of a package's public names (its ``__all__``), imported when first used

"""

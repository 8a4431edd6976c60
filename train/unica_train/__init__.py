"""The unica trainer: reads datasets baked by `unica bake`, trains the geometry model and
writes bundles that the Rust app loads. See train/README.md."""

import os as _os


def _die_with_parent() -> None:
    """Under `unica make` (UNICA_DIE_WITH_PARENT=the make's pid in the environment)
    every trainer process, torchrun (started as unica_train.torchrun) and its workers too,
    dies with the process that started it (Linux PR_SET_PDEATHSIG), so a make killed with
    SIGKILL leaves no trainer writing into its folder while the same make runs again."""
    try:
        make = int(_os.environ.get("UNICA_DIE_WITH_PARENT", ""))
    except ValueError:
        return
    import ctypes
    import signal

    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return  # not Linux: nothing to ask for
    # Taken in by init: the parent died before the request (unless init is the make
    # itself, as a container's entry point).
    if _os.getppid() == 1 and make != 1:
        _os._exit(1)


_die_with_parent()

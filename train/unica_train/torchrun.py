"""`python -m unica_train.torchrun ARGS` is `python -m torch.distributed.run ARGS` (torchrun)
run as part of the trainer, so that under `unica make` it asks to die with the make like
every trainer process (`_die_with_parent` in __init__.py). Plain torchrun never imports the
trainer: a make killed with SIGKILL left it running, and a CI machine measured it still
there 10 s later; its workers ask to die with it, so they go too."""

from torch.distributed.run import main

if __name__ == "__main__":
    main()

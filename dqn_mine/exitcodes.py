"""Exit codes of the command-line tools (train, play, evaluate, plot) and of the sweep launcher."""

EXIT_OK = 0
EXIT_FAILED = 1           # an actor or the learner failed (a checkpoint is kept)
EXIT_BAD_INPUT = 2        # bad flags, an impossible configuration, a corrupt run folder
EXIT_INTERRUPTED = 130    # stopped by a signal (128 + SIGINT, as shells report it)

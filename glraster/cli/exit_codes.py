"""The exit codes of every ``glraster`` command (README, "Conformance suite")."""

OK = 0          # the command did its job; checks passed
FAIL = 1        # a check, comparison or golden failed
USAGE = 2       # bad input: arguments, files, scenes, an address to listen on (names what)
NO_BACKEND = 3  # no headless OpenGL context could be made (library, driver or environment)
INTERRUPTED = 130  # Ctrl-C (SIGINT): 128 + 2, as shells report it; no partial file is left
TERMINATED = 143  # SIGTERM (a CI job cancelled or timed out): 128 + 15; no partial file is left
BROKEN_PIPE = 141  # the reader of stdout went away (`glraster check --list | head -1`): 128 + 13

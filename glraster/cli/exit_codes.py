"""The exit codes of every ``glraster`` command (README, "Conformance suite")."""

OK = 0          # the command did its job; checks passed
FAIL = 1        # a check, comparison or golden failed
USAGE = 2       # bad input: arguments, files, scenes (the message names what)
NO_BACKEND = 3  # no headless OpenGL context could be made

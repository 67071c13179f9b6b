"""Source for a subprocess that must run with moderngl and glcontext unimportable: a finder
first on ``sys.meta_path`` refuses them, as on a machine where they are not installed."""

import textwrap

BLOCK_GL = textwrap.dedent("""
    import sys

    class NoGL:
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in ("moderngl", "glcontext"):
                raise ImportError(f"No module named {name!r} (blocked by the test)")
            return None

    sys.meta_path.insert(0, NoGL())
""")

"""The interpreter that runs one Markdown file's ```python blocks, in order.

Started by :mod:`tests.docs.markdown_blocks` as ``python block_worker.py REQUEST_FD
REPLY_FD`` in the file's empty temporary folder, one fresh process per file. Each request
is one JSON line ``{"path": "README.md", "line": 34, "source": "..."}``; the block runs in
the namespace that the file's earlier blocks left (``__name__ == "__main__"``), compiled
with the Markdown file's name and line numbers so that a traceback points into the file.
Each reply is one JSON line ``{"ok": true}`` or ``{"ok": false, "error": "<traceback>"}``.
The blocks' own stdout and stderr go wherever the parent sent this process's.
"""

from __future__ import annotations

import json
import os
import sys
import traceback


def main(request_fd: int, reply_fd: int) -> None:
    namespace = {"__name__": "__main__", "__builtins__": __builtins__}
    requests = os.fdopen(request_fd, "r", encoding="utf-8")
    replies = os.fdopen(reply_fd, "w", encoding="utf-8")
    for request_line in requests:
        request = json.loads(request_line)
        # Blank lines in front: the code object's line numbers are the Markdown file's.
        source = "\n" * (request["line"] - 1) + request["source"]
        try:
            code = compile(source, request["path"], "exec")
            exec(code, namespace)
            reply = {"ok": True}
        except BaseException:  # noqa: BLE001 - a block's SystemExit is a failure too
            kind, value, tb = sys.exc_info()
            # Drop this file's own frame: the traceback starts in the block.
            reply = {"ok": False,
                     "error": "".join(traceback.format_exception(kind, value, tb.tb_next))}
        sys.stdout.flush()
        sys.stderr.flush()
        replies.write(json.dumps(reply) + "\n")
        replies.flush()


if __name__ == "__main__":
    main(int(sys.argv[1]), int(sys.argv[2]))

"""JUnit XML for CI systems (GitLab, Jenkins, GitHub test reporters) from a check run.

One ``<testsuite name="glraster.conformance.check">`` with a ``<testcase>`` per scene (classname
``glraster.conformance.check.<backend>``, plus ``.<method>`` for a method other than hw) and, after a mutant pass, a ``<testsuite
name="glraster.conformance.mutants">`` with a testcase per mutant (failing when it escaped) plus one
for the control run of the real shaders. Failures carry a one-line message and the full
comparison summary as text. The file is written atomically.
"""

from __future__ import annotations

import os
import socket
import tempfile
import xml.etree.ElementTree as ET
from datetime import datetime, timezone
from pathlib import Path


def _case(parent, classname, name, seconds, failure=None, error=None, out=None):
    case = ET.SubElement(parent, "testcase", classname=classname, name=name,
                         time=f"{seconds:.3f}")
    if error:
        ET.SubElement(case, "error", message=error[:500], type="error").text = error
    elif failure:
        msg, text = failure
        ET.SubElement(case, "failure", message=msg[:500], type="failure").text = text
    if out:
        ET.SubElement(case, "system-out").text = out
    return case


def to_xml(result) -> ET.ElementTree:
    """An ElementTree for a :class:`glraster.conformance.check.CheckResult`."""
    root = ET.Element("testsuites", name="glraster")
    stamp = datetime.now(timezone.utc).isoformat(timespec="seconds")
    suite = ET.SubElement(root, "testsuite", name="glraster.conformance.check", timestamp=stamp,
                          hostname=socket.gethostname())
    props = ET.SubElement(suite, "properties")
    for k, v in (("backend", result.backend), ("renderer", result.renderer),
                 ("gl_version", result.gl_version), ("method", result.method)):
        ET.SubElement(props, "property", name=k, value=str(v))
    fails = errors = 0
    cls = f"glraster.conformance.check.{result.backend}" + (
        f".{result.method}" if result.method != "hw" else "")
    for s in result.scenes:
        summary = s.report.summary() if s.report is not None else ""
        if s.golden is not None:
            summary += f"\ngolden: {s.golden.message}; max |GPU - golden| {s.golden_max_error:.3g}"
        if s.waived:
            summary += f"\nnot judged (documented driver deviation, see ErrorModel): {s.waived}"
        h, w = s.resolution
        tris = f"{s.triangles} triangle" + ("" if s.triangles == 1 else "s")
        summary = f"{s.description}\n{w}x{h}, {tris}\n{summary}"
        if s.status == "error":
            errors += 1
            _case(suite, cls, s.name, s.seconds, error=s.error, out=summary)
        elif s.status == "fail":
            fails += 1
            _case(suite, cls, s.name, s.seconds,
                  failure=("; ".join(s.failures), summary), out=summary)
        else:
            _case(suite, cls, s.name, s.seconds, out=summary)
    suite.set("tests", str(len(result.scenes)))
    suite.set("failures", str(fails))
    suite.set("errors", str(errors))
    suite.set("skipped", "0")
    suite.set("time", f"{sum(s.seconds for s in result.scenes):.3f}")
    total = (len(result.scenes), fails, errors)

    if result.mutants is not None:
        ms = ET.SubElement(root, "testsuite", name="glraster.conformance.mutants", timestamp=stamp)
        mf = me = 0
        for m in result.mutants:
            if m.error:
                me += 1
                _case(ms, "glraster.conformance.mutants", m.name, m.seconds,
                      error=f"mutant could not run: {m.error}", out=m.fault)
            elif not m.caught:
                mf += 1
                _case(ms, "glraster.conformance.mutants", m.name, m.seconds,
                      failure=(f"mutant escaped: {m.fault}",
                               f"no scene out of {m.scenes_tried} detected: {m.fault}"))
            else:
                _case(ms, "glraster.conformance.mutants", m.name, m.seconds,
                      out=f"{m.fault}\ncaught by {m.caught_by}: {m.reason}")
        control_fail = None
        if result.control_failures:
            mf += 1
            control_fail = ("real shaders failed through the mutant path",
                            "false alarm on: " + ", ".join(result.control_failures))
        _case(ms, "glraster.conformance.mutants", "control_real_shaders", 0.0, failure=control_fail)
        n = len(result.mutants) + 1
        ms.set("tests", str(n))
        ms.set("failures", str(mf))
        ms.set("errors", str(me))
        ms.set("skipped", "0")
        ms.set("time", f"{sum(m.seconds for m in result.mutants):.3f}")
        total = (total[0] + n, total[1] + mf, total[2] + me)
    root.set("tests", str(total[0]))
    root.set("failures", str(total[1]))
    root.set("errors", str(total[2]))
    root.set("time", f"{result.seconds:.3f}")
    ET.indent(root)
    return ET.ElementTree(root)


def write(result, path) -> Path:
    """Write the JUnit XML of ``result`` to ``path`` atomically; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            to_xml(result).write(fh, encoding="utf-8", xml_declaration=True)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path

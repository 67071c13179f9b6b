"""JUnit XML for CI systems (GitLab, Jenkins, GitHub test reporters) from a check run.

One ``<testsuite name="glraster.conformance.check">`` with a ``<testcase>`` per scene (classname
``glraster.conformance.check.<backend>``, plus ``.<method>`` for a method other than hw; a
fleet run of :mod:`glraster.cluster` puts the driver first, ``...check.<driver>.<backend>``,
and a ``driver`` property on the suite) and, after a mutant pass, a ``<testsuite
name="glraster.conformance.mutants">`` with a testcase per mutant (failing when it escaped) plus one
for the control run of the real shaders. Failures carry a one-line message and the full
comparison summary as text. The file is written atomically.

A run that was one shard of a split catalog (``glraster check --shard I/N``) carries a
``shard`` property ``I/N``; :func:`merge` joins the files of all shards (of one or several
drivers and methods) into one report, and refuses an incomplete or overlapping set.
"""

from __future__ import annotations

import socket
import xml.etree.ElementTree as ET
from datetime import datetime, timezone
from pathlib import Path

from glraster.errors import ArgumentError
from glraster.io.atomic import atomic_write


def _set_counts(element, tests, failures, errors, seconds, skipped=0) -> None:
    """The JUnit count attributes of a <testsuite> (``skipped=None``: of <testsuites>)."""
    element.set("tests", str(tests))
    element.set("failures", str(failures))
    element.set("errors", str(errors))
    if skipped is not None:
        element.set("skipped", str(skipped))
    element.set("time", f"{seconds:.3f}")


def _case(parent, classname, name, seconds, failure=None, error=None, out=None,
          properties=None):
    case = ET.SubElement(parent, "testcase", classname=classname, name=name,
                         time=f"{seconds:.3f}")
    if properties:
        props = ET.SubElement(case, "properties")
        for key, value in properties.items():
            ET.SubElement(props, "property", name=key, value=str(value))
    if error:
        ET.SubElement(case, "error", message=error[:500], type="error").text = error
    elif failure:
        msg, text = failure
        ET.SubElement(case, "failure", message=msg[:500], type="failure").text = text
    if out:
        ET.SubElement(case, "system-out").text = out
    return case


def _probe_suite(root, result, stamp, total):
    """The ``glraster.conformance.probes`` suite: a test case per probe (a failure names
    the defect; a documented deviation passes and says so); returns the updated totals."""
    ps = ET.SubElement(root, "testsuite", name="glraster.conformance.probes", timestamp=stamp)
    cls = "glraster.conformance.probes"
    driver = getattr(result, "driver", None)
    if driver:  # a fleet run: one probe suite per driver
        ET.SubElement(ET.SubElement(ps, "properties"), "property", name="driver", value=driver)
        cls += f".{driver}"
    pf = pe = 0
    for p in result.probes:
        out = f"{p.expectation}\n{p.spec}\n{p.detail}".strip()
        if p.explains:
            out += f"\nexplains the failures of: {', '.join(p.explains)}"
        if p.status == "error":
            pe += 1
            _case(ps, cls, p.name, p.seconds, error=p.diagnosis, out=out)
        elif p.status == "fail":
            pf += 1
            _case(ps, cls, p.name, p.seconds,
                  failure=(p.diagnosis, out), out=out)
        else:
            note = {"known": f"known driver deviation: {p.diagnosis}",
                    "skipped": "not run on this context"}.get(p.status, "")
            _case(ps, cls, p.name, p.seconds,
                  out=f"{note}\n{out}".strip())
    _set_counts(ps, len(result.probes), pf, pe, sum(p.seconds for p in result.probes))
    return (total[0] + len(result.probes), total[1] + pf, total[2] + pe)


def to_xml(result) -> ET.ElementTree:
    """An ElementTree for a :class:`glraster.conformance.check.CheckResult`."""
    root = ET.Element("testsuites", name="glraster")
    stamp = datetime.now(timezone.utc).isoformat(timespec="seconds")
    suite = ET.SubElement(root, "testsuite", name="glraster.conformance.check", timestamp=stamp,
                          hostname=socket.gethostname())
    props = ET.SubElement(suite, "properties")
    driver = getattr(result, "driver", None)
    for k, v in ((("driver", driver),) if driver else ()) + (
            ("backend", result.backend), ("renderer", result.renderer),
            ("gl_version", result.gl_version), ("method", result.method)):
        ET.SubElement(props, "property", name=k, value=str(v))
    shard = getattr(result, "shard", None)
    if shard:
        ET.SubElement(props, "property", name="shard", value=f"{shard[0]}/{shard[1]}")
    if getattr(result, "rules", None) is not None:
        ET.SubElement(props, "property", name="rules", value=result.rules.summary())
    fails = errors = 0
    cls = "glraster.conformance.check." + (f"{driver}." if driver else "") + result.backend + (
        f".{result.method}" if result.method != "hw" else "")
    for s in result.scenes:
        summary = s.report.summary() if s.report is not None else ""
        if s.golden is not None:
            summary += f"\ngolden: {s.golden.message}; max |GPU - golden| {s.golden_max_error:.3g}"
        if s.waived:
            summary += f"\nnot judged (documented driver deviation, see ErrorModel): {s.waived}"
        h, w = s.resolution
        tris = f"{s.triangles} triangle" + ("" if s.triangles == 1 else "s")
        sampling = getattr(s, "sampling", "1")
        sampling = "1 sample" if sampling == "1" else \
            f"{s.samples} samples, interpolation {s.interpolation}"
        summary = f"{s.description}\n{h}x{w} (HxW), {tris}, {sampling}\n{summary}"
        for probe, diagnosis in getattr(s, "explained_by", ()):
            summary += f"\nexplained by probe {probe}: {diagnosis}"
        props = {"samples": getattr(s, "samples", 1),
                 "interpolation": getattr(s, "interpolation", "center")}
        if s.status == "error":
            errors += 1
            _case(suite, cls, s.name, s.seconds, error=s.error, out=summary, properties=props)
        elif s.status == "fail":
            fails += 1
            _case(suite, cls, s.name, s.seconds,
                  failure=("; ".join(s.failures), summary), out=summary, properties=props)
        else:
            _case(suite, cls, s.name, s.seconds, out=summary, properties=props)
    _set_counts(suite, len(result.scenes), fails, errors, sum(s.seconds for s in result.scenes))
    total = (len(result.scenes), fails, errors)
    if getattr(result, "probes", None) and (not shard or shard[0] == 1):
        total = _probe_suite(root, result, stamp, total)  # one shard reports the probes

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
        _set_counts(ms, n, mf, me, sum(m.seconds for m in result.mutants))
        total = (total[0] + n, total[1] + mf, total[2] + me)
    _set_counts(root, *total, result.seconds, skipped=None)
    ET.indent(root)
    return ET.ElementTree(root)


def to_string(result) -> str:
    """The JUnit XML of ``result`` as a string (with the XML declaration)."""
    return ET.tostring(to_xml(result).getroot(), encoding="unicode", xml_declaration=True)


class MergeError(ValueError):
    """JUnit files that do not form one complete run: a shard missing or given twice, a
    scene reported by two shards, shards of one driver that disagree on the renderer."""


def _props(suite) -> dict:
    return {p.get("name"): p.get("value") for p in suite.iterfind("properties/property")}


def merge(sources) -> ET.ElementTree:
    """One JUnit tree from the files (paths or ElementTrees) of ``glraster check`` runs.

    Suites are grouped by name, backend, method and driver (a fleet run's): the shards of one driver's run become
    one suite again (test cases in the shards' order, counts and times summed), runs of
    different drivers or methods stay separate suites. For every group with ``shard``
    properties, shards 1..N must each appear exactly once (MergeError otherwise), and no
    test case may appear twice in a group.
    """
    groups: dict = {}
    order = []
    for src in sources:
        try:
            tree = src if isinstance(src, ET.ElementTree) else ET.parse(src)
        except ET.ParseError as exc:
            raise ArgumentError("inputs", f"{src}: not well-formed XML ({exc})") from None
        root = tree.getroot()
        if root.tag not in ("testsuites", "testsuite"):
            raise ArgumentError("inputs", f"{src}: not a JUnit file (its root element is "
                                          f"<{root.tag}>, not <testsuites> or <testsuite>)")
        suites = [root] if root.tag == "testsuite" else list(root.iterfind("testsuite"))
        for suite in suites:
            props = _props(suite)
            key = (suite.get("name"), props.get("backend"), props.get("method"),
                   props.get("driver"))
            if key not in groups:
                groups[key] = []
                order.append(key)
            groups[key].append((suite, props, str(src)))
    out = ET.Element("testsuites", name="glraster")
    totals = [0, 0, 0, 0.0]
    for key in order:
        members = groups[key]
        shards = [p.get("shard") for _, p, _ in members if p.get("shard")]
        if shards:
            counts = {s.split("/")[1] for s in shards}
            if len(counts) != 1:
                raise MergeError(f"suite {key[0]} ({key[1]}, {key[2]}): shards of different "
                                 f"splits {sorted(set(shards))}")
            n = int(counts.pop())
            seen = sorted(int(s.split("/")[0]) for s in shards)
            missing = sorted(set(range(1, n + 1)) - set(seen))
            twice = sorted({i for i in seen if seen.count(i) > 1})
            is_mutants = key[0] == "glraster.conformance.mutants"
            if (missing and not is_mutants) or twice:
                raise MergeError(
                    f"suite {key[0]} ({key[1]}, method {key[2]}): "
                    + (f"shards {missing} of {n} missing" if missing else "")
                    + ("; " if missing and twice else "")
                    + (f"shards {twice} given twice" if twice else ""))
        renderers = {p.get("renderer") for _, p, _ in members if p.get("renderer")}
        if len(renderers) > 1:
            raise MergeError(f"suite {key[0]} ({key[1]}, method {key[2]}): the files come "
                             f"from different renderers {sorted(renderers)}")
        first, props, _ = members[0]
        suite = ET.SubElement(out, "testsuite", name=first.get("name") or "")
        stamps = [m.get("timestamp") for m, _, _ in members if m.get("timestamp")]
        if stamps:
            suite.set("timestamp", min(stamps))
        hosts = sorted({m.get("hostname") for m, _, _ in members if m.get("hostname")})
        if hosts:
            suite.set("hostname", ",".join(hosts))
        pe = ET.SubElement(suite, "properties")
        for k, v in props.items():
            if k != "shard":
                ET.SubElement(pe, "property", name=k, value=v)
        if shards:
            ET.SubElement(pe, "property", name="shards", value=str(len(set(shards))))
        names = set()
        tests = fails = errs = skips = 0
        seconds = 0.0
        for member, _, src in members:
            for case in member.iterfind("testcase"):
                ident = (case.get("classname"), case.get("name"))
                if ident in names:
                    raise MergeError(f"test case {ident[1]} ({ident[0]}) appears twice "
                                     f"(again in {src})")
                names.add(ident)
                suite.append(case)
                tests += 1
                fails += case.find("failure") is not None
                errs += case.find("error") is not None
                skips += case.find("skipped") is not None
                seconds += float(case.get("time") or 0)
        _set_counts(suite, tests, fails, errs, seconds, skips)
        totals = [totals[0] + tests, totals[1] + fails, totals[2] + errs, totals[3] + seconds]
    _set_counts(out, *totals, skipped=None)
    ET.indent(out)
    return ET.ElementTree(out)


def write_tree(tree: ET.ElementTree, path) -> Path:
    """Write a JUnit ElementTree to ``path`` atomically (the parent folder is created);
    returns the path."""
    path = Path(path)
    with atomic_write(path) as tmp:
        tree.write(tmp, encoding="utf-8", xml_declaration=True)
    return path


def write(result, path) -> Path:
    """Write the JUnit XML of ``result`` to ``path`` atomically; returns the path."""
    return write_tree(to_xml(result), path)

"""``python -m inspector_tools.precompile``: the install step that compiles the kernels, with progress."""

from __future__ import annotations

import json


def _helper(x):
    return x * 2


def _kernel(x):
    return _jhelper(x) + 1


_helper.__module__ = _kernel.__module__ = "inspector.kernels.fake"  # only the project's kernels are named
_jhelper = None


def test_progress_names_each_kernel_once_and_times_it():
    import numba

    from inspector_tools.precompile import _Progress

    global _jhelper
    _jhelper = numba.njit(_helper)
    jkernel = numba.njit(_kernel)
    lines: list[str] = []
    with _Progress(lines.append) as progress:
        assert jkernel(3) == 7
        assert jkernel(4) == 9  # compiled once
    assert lines[0] == "  compiling fake._kernel ..." and lines[-1].startswith("  compiled  fake._kernel in ")
    assert len(lines) == 2  # the nested helper is part of the kernel's line
    assert [name for name, _ in progress.kernels] == ["fake._kernel"]


def test_precompile_inspects_the_small_captures_with_the_builtin_recipes(tmp_path, capsys, monkeypatch):
    """``python -m inspector_tools.precompile`` in process (the kernels are cached by now: the
    same inspections, loading them): a good and a notched cube through both recipes."""
    from inspector_tools import precompile

    seen = {}
    real = precompile.precompile

    def spy(work, say=print, **kw):
        seen.update(real(work, say, **kw))
        return seen

    monkeypatch.setattr(precompile, "precompile", spy)
    assert precompile.main([]) == 0
    assert seen["verdicts"] == {"demo.toml": {"good": "pass", "notched": "fail"},
                                "default.toml": {"good": "pass", "notched": "fail"}}
    out = capsys.readouterr()
    lines = out.out.splitlines()
    assert lines[0].startswith("Compiling the inspection kernels")
    assert lines[-1].startswith("Kernels ready in ") and lines[-1].endswith("the small captures: good pass, notched fail).")
    assert "Traceback" not in out.err
    # the kernel list the install compiles ahead is what this run used (else: --record)
    from inspector_tools.precompile import SIGNATURES, _argument_types, _dispatcher

    entries = json.loads(SIGNATURES.read_text(encoding="utf-8"))
    assert {e["name"] for e in entries} >= {"_finest_kernel", "_select_kernel", "_march_squares"}
    for e in entries:
        disp = _dispatcher(e["module"], e["name"])
        assert disp is not None, e
        assert _argument_types(e["args"]) in [tuple(s) for s in disp.signatures], e


def test_groups_are_balanced_and_a_bad_entry_is_one_line():
    from inspector_tools.precompile import compile_listed, split

    entries = [{"module": "m", "name": n, "seconds": s} for n, s in (("a", 20), ("b", 19), ("c", 9), ("d", 8), ("e", 2))]
    groups = split(entries, 2)
    assert sorted(sum(e["seconds"] for e in g) for g in groups) == [28, 30]
    lines: list[str] = []
    problems = compile_listed([{"module": "inspector.kernels.carving_jit", "name": "nope", "args": "(int64,)"}],
                              lines.append)
    assert problems == ["inspector.kernels.carving_jit.nope: LookupError: no such kernel"] and lines == []

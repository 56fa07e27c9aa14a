"""Fuzzing the command line with hostile and careless input (the corpus is ``fuzz_corpus.py``).

The promise checked for every case: the exit status (2 for bad input, 1 for a batch with some bad frames, 0 where
the input is fine and the result must be right); on an error exactly one non-empty line on stderr (fd 2, so
C-library chatter counts too) that names the offending file or option; no traceback; no output left behind (no new
file anywhere, no ``*.part*`` temporaries); every input file byte-for-byte unchanged, and FIFOs and devices still
what they were.

Cases run in-process through ``lowcam.cli.main`` (with ``capfd``); memory-hungry or hang-prone ones run as
``python -m lowcam.cli`` under an address-space limit and a timeout. A few cases run as a real process on purpose:
argparse's ``SystemExit`` and Ctrl-C (SIGINT to the process group, as a terminal sends it) during a batch.
"""
from __future__ import annotations

import hashlib
import os
import re
import signal
import stat
import subprocess
import sys
import time
import traceback
from pathlib import Path

import pytest

import fuzz_corpus as corpus
from fuzz_corpus import CASES, ROOT, Case

# --- running a case ------------------------------------------------------------------------------------------------


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def snapshot(root: Path) -> dict[Path, str]:
    """Every file under ``root``: regular files by content hash, anything else (FIFO, device) by its type. Never
    opens a special file (that could block)."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in filenames + [d for d in dirnames if os.path.islink(os.path.join(dirpath, d))]:
            p = Path(dirpath) / name
            try:
                st = os.lstat(p)
            except FileNotFoundError:
                continue
            if stat.S_ISREG(st.st_mode):
                try:
                    out[p] = _sha256(p)
                except OSError as e:  # an unreadable file: its mode and size stand in
                    out[p] = f"unreadable {e.errno} {st.st_size}"
            else:
                out[p] = f"type {stat.S_IFMT(st.st_mode):o}"
    return out


def _limit_memory(gb: float | None):
    if gb is None:
        return None

    def limit():
        import resource

        n = int(gb * 2**30)
        resource.setrlimit(resource.RLIMIT_AS, (n, n))
    return limit


def run_in_process(argv: list[str], capfd) -> tuple[int, str, str]:
    """``lowcam.cli.main(argv)``; an exception escaping main is printed as the interpreter would (exit 1)."""
    from lowcam.cli import main

    capfd.readouterr()
    try:
        rc = main(argv)
    except SystemExit as e:
        rc = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    except BaseException:  # noqa: BLE001 - what the user would see
        traceback.print_exc()
        rc = 1
    sys.stdout.flush()
    sys.stderr.flush()
    out, err = capfd.readouterr()
    return rc, out, err


def run_subprocess(argv: list[str], cwd: Path, timeout: float, mem_limit_gb: float | None = None):
    proc = subprocess.Popen([sys.executable, "-m", "lowcam.cli", *argv], cwd=cwd, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=_limit_memory(mem_limit_gb))
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        _kill_group(proc)
        out, err = proc.communicate()
        pytest.fail(f"hung: no exit within {timeout:.0f} s; stderr tail:\n{_tail(err)}")
    finally:
        _kill_group(proc)
    return proc.returncode, out, err


def _kill_group(proc: subprocess.Popen) -> None:
    """Kill what is left of the process group we started (Dask workers included)."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


def _lines(text: str) -> list[str]:
    return [ln for ln in text.replace("\r", "\n").splitlines() if ln.strip()]


def _tail(err: str, n: int = 4) -> str:
    return "\n".join(_lines(err)[-n:]) or "(stderr empty)"


def traceback_summary(err: str) -> str:
    """The one-line tail of a traceback: the last frame in Lowcam's code (else the last frame) and the exception."""
    lines = _lines(err)
    frames = [ln.strip() for ln in lines if ln.lstrip().startswith('File "')]
    ours = [f for f in frames if "/lowcam/" in f or "/addon/" in f or "/nodes/" in f] or frames
    exc = next((ln.strip() for ln in reversed(lines) if not ln.startswith(" ")), "")
    if not ours:
        return exc
    m = re.match(r'File "(?P<file>[^"]+)", line (?P<line>\d+), in (?P<func>.+)', ours[-1])
    where = f"{Path(m['file']).relative_to(ROOT) if m['file'].startswith(str(ROOT)) else m['file']}:{m['line']} " \
            f"in {m['func']}" if m else ours[-1]
    return f"{where}: {exc}"


def _part_files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*.part*"))


def check_case(case: Case, folder: Path, root: Path, rc: int, out: str, err: str, before: dict,
               before_inputs: dict) -> None:
    lines = _lines(err)
    traceback_shown = "Traceback" in err
    assert not traceback_shown, f"exit {rc}, a traceback: {traceback_summary(err)}"
    assert rc in case.rc, f"exit {rc}, expected {' or '.join(map(str, case.rc))}; stderr tail:\n{_tail(err)}"

    if rc == 2:
        assert len(lines) == 1, f"{len(lines)} lines on stderr, expected 1:\n" + "\n".join(lines[:8])
        line = lines[0]
        if case.names:
            assert any(n in line for n in case.names), f"the error line names none of {case.names}: {line!r}"
        for n in case.also:
            assert n in line, f"the error line does not name {n!r}: {line!r}"
    elif rc == 1:
        for f in case.bad_frames:
            hits = [ln for ln in lines if f"frame {f}" in ln and (not case.names or any(n in ln for n in case.names))]
            assert hits, f"frame {f} is not named with any of {case.names}:\n" + "\n".join(lines[:8])
        assert len(lines) <= 2 + len(case.bad_frames), \
            f"{len(lines)} lines on stderr for {len(case.bad_frames)} bad frames:\n" + "\n".join(lines[:10])
    else:
        chatter = [ln for ln in lines if any(w in ln for w in ("Warning", "WARN", "rror", "Premature", "Corrupt"))]
        assert not chatter, "exit 0 but warnings on stderr:\n" + "\n".join(chatter[:5])

    # never a changed input; special files keep their type
    after = snapshot(root)
    changed = [p for p, h in before.items() if after.get(p) != h and not (rc == 0 and p in case.may_change)]
    assert not changed, "inputs changed or removed: " + ", ".join(
        f"{p.relative_to(root)} ({before[p][:12]} -> {str(after.get(p, 'missing'))[:12]})" for p in changed)
    for p, h in before_inputs.items():
        assert (_sha256(p) if p.is_file() else "missing") == h, f"input {p} changed"
    for p in case.special:
        assert os.path.lexists(p) and not stat.S_ISREG(os.lstat(p).st_mode), f"{p.name} was replaced by a file"

    # nothing left behind
    parts = _part_files(root)
    assert not parts, "temporaries left behind: " + ", ".join(str(p.relative_to(root)) for p in parts)
    if rc == 2:
        new = sorted(p for p in after if p not in before)
        assert not new, "an error left files behind: " + ", ".join(str(p.relative_to(root)) for p in new)
    if rc != 0:
        for p in case.outputs:
            existed = p in before
            assert existed or not os.path.lexists(p), f"output {p.name} left behind after exit {rc}"
    if case.check:
        case.check(folder, rc, out, err)


def _params():
    for name, (_, marks) in CASES.items():
        yield pytest.param(name, id=name, marks=[getattr(pytest.mark, m) for m in marks])


@pytest.mark.timeout(300)
@pytest.mark.parametrize("name", list(_params()))
def test_fuzz_case(name, tmp_path, capfd, monkeypatch):
    folder = tmp_path / "case"
    case = corpus.build(name, folder)
    if case.skip:
        pytest.skip(case.skip)
    before = snapshot(tmp_path)
    before_inputs = {p: _sha256(p) if p.is_file() else "missing" for p in case.inputs}
    monkeypatch.chdir(folder)
    try:
        if case.subprocess:
            rc, out, err = run_subprocess(case.argv, folder, case.timeout, case.mem_limit_gb)
        else:
            rc, out, err = run_in_process(case.argv, capfd)
        check_case(case, folder, tmp_path, rc, out, err, before, before_inputs)
    finally:
        for d in (folder / "readonly",):  # let pytest clean up
            if d.exists():
                d.chmod(0o755)


# --- argparse: SystemExit in a real process ------------------------------------------------------------------------

# argparse prints its usage line(s) before 'lowcam ...: error: ...'. Judgement call: the usage is allowed, but
# exactly one line must say 'error:' and name the option, and nothing else may appear.
@pytest.mark.parametrize("argv, rc, names", [
    pytest.param([], 2, ("command",), id="no-command"),
    pytest.param(["frobnicate"], 2, ("frobnicate",), id="unknown-command"),
    pytest.param(["apply", "--render", "r.exr", "-o", "o.png", "--seed", "abc"], 2, ("--seed",), id="seed-not-int"),
    pytest.param(["apply", "--render", "r.exr", "-o", "o.png", "--seed", "1e3"], 2, ("--seed",), id="seed-float"),
    pytest.param(["apply", "--render", "r.exr", "-o", "o.png", "--angular-velocity", "nan,0,0"], 2,
                 ("--angular-velocity",), id="angular-velocity-nan"),
    pytest.param(["apply", "--render", "r.exr"], 2, ("-o", "--output"), id="apply-without-output"),
    pytest.param(["batch", "--renders", "r/####.exr", "--frames", "1", "-o", "o/####.png", "--workers", "two"], 2,
                 ("--workers",), id="workers-not-int"),
    pytest.param(["--help"], 0, (), id="help"),
])
def test_systemexit_in_a_real_process(argv, rc, names, tmp_path):
    got, out, err = run_subprocess(argv, tmp_path, 60)
    traceback_shown = "Traceback" in err
    assert not traceback_shown, traceback_summary(err)
    assert got == rc, f"exit {got}, expected {rc}: {_tail(err)}"
    if rc == 0:
        assert "usage:" in out and not err.strip()
        return
    lines = _lines(err)
    errors = [ln for ln in lines if "error:" in ln]
    other = [ln for ln in lines if "error:" not in ln and not ln.startswith("usage:") and not ln.startswith(" ")]
    assert len(errors) == 1 and not other, "stderr:\n" + "\n".join(lines)
    assert any(n in errors[0] for n in names), errors[0]
    assert not list(tmp_path.iterdir()), "files left behind"


# --- Ctrl-C during a batch -----------------------------------------------------------------------------------------

def _interrupt_batch(tmp_path: Path, workers: int, frames: int = 60):
    renders = corpus.write_renders(tmp_path, range(1, frames + 1))
    out = tmp_path / "out"
    argv = ["batch", "--renders", renders, "--frames", f"1-{frames}", "-o", str(out / "####.png"), "--quiet"]
    if workers:
        argv += ["--workers", str(workers)]
    before = snapshot(tmp_path)
    # a user at a terminal: Ctrl-C is not ignored, even when this suite runs in a script's background
    # (started with SIGINT ignored, a disposition children inherit)
    proc = subprocess.Popen([sys.executable, "-m", "lowcam.cli", *argv], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        t0 = time.monotonic()
        # wait for the first frame (the batch is really running), then Ctrl-C the whole process group
        while time.monotonic() - t0 < 60 and proc.poll() is None and not (out.exists() and any(out.glob("*.png"))):
            time.sleep(0.05)
        time.sleep(0.3)
        # on a starved machine the batch may be finishing: a Ctrl-C then meets no work (exit 0 is right)
        if proc.poll() is not None or len(list(out.glob("*.png"))) > frames - 5:
            pytest.skip(f"the batch (nearly) ended before it could be interrupted (exit {proc.poll()})")
        os.killpg(proc.pid, signal.SIGINT)
        try:
            _, err = proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            _kill_group(proc)
            _, err = proc.communicate()
            pytest.fail(f"still running 60 s after Ctrl-C; stderr tail:\n{_tail(err)}")
    finally:
        _kill_group(proc)
    lines = _lines(err)
    traceback_shown = "Traceback" in err
    assert not traceback_shown, f"a traceback after Ctrl-C: {traceback_summary(err)}\n{_tail(err, 40)}"
    assert len(lines) <= 2, f"{len(lines)} lines on stderr after Ctrl-C:\n" + "\n".join(lines[:10])
    assert proc.returncode == 130, f"exit {proc.returncode} after Ctrl-C, expected 130: {_tail(err)}"
    assert not _part_files(tmp_path), "temporaries left behind: " + ", ".join(map(str, _part_files(tmp_path)))
    after = snapshot(tmp_path)
    assert all(after.get(p) == h for p, h in before.items()), "a render changed"
    import cv2

    for p in out.glob("*"):  # every frame that exists is complete (atomic writes)
        assert cv2.imread(str(p)) is not None, f"{p.name} is not a complete PNG"


@pytest.mark.timeout(180)
def test_ctrl_c_serial_batch(tmp_path):
    _interrupt_batch(tmp_path, workers=0)


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_ctrl_c_dask_batch_with_2_workers(tmp_path):
    _interrupt_batch(tmp_path, workers=2)

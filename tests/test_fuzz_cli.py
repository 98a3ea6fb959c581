"""
The CLI fuzzed at its boundaries (hypothesis): hostile option values (names, paths, numbers, unicode, Ray
addresses, storage URLs), hostile bundle zips (member names with traversal, odd sizes, odd JSON), hostile
workers manifests and benchmark records, and term specs, given to the real ``hddpg-cli`` commands.

Every command runs in one long-lived interpreter (:data:`SERVER`, the CLI's own entry point as
``tests/cli_batch.py`` runs it, so torch loads once) under ``prlimit --as`` and a per-command time bound, in
a fresh sandbox per example: a fake ``HOME``, a current folder and a user's folder holding the user's files,
an earlier run folder of the tool holding one of the user's files too, and the hostile inputs. After each
command, whatever it was:

- it exited 0, or 2 with exactly one line on stderr (``error: ...``), never a traceback or exit 1;
- it stayed under the memory bound (a ``MemoryError`` would be exit 1; a kill ends the server) and the time
  bound;
- nothing appeared outside the command's own output (``--out``, ``--json``);
- nothing it did not write is gone or changed: every file of the user's, wherever it was, is intact, and the
  home folder is still empty.

The default run tries :data:`FAST_EXAMPLES` examples per property (the whole file in well under a minute of
CPU); ``-m slow`` runs the same properties with :data:`LONG_EXAMPLES`.
"""

from __future__ import annotations

import io
import itertools
import json
import os
import select
import shutil
import subprocess
import sys
import textwrap
import time
import warnings
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

REPO = Path(__file__).resolve().parents[1]
WORKER = REPO / "docs" / "results" / "models" / "seed-0" / "workers" / "goal.zip"
#: Address-space bound of the interpreter running the commands (torch, SB3, Optuna loaded: ~1.5 GiB).
MEMORY_BOUND = 4 << 30
#: Seconds one command may take (the valid ones train or package a few steps).
TIME_BOUND = 90.0
FAST_EXAMPLES = 12
LONG_EXAMPLES = 60
#: What the server prefixes its answers with: commands' children may write to the same stdout.
MARK = "@@fuzz@@"

SERVER = textwrap.dedent(
    f"""
    import json, os, sys, time
    os.environ.pop("HDDPG_DEBUG", None)
    from tests.cli_batch import run_one
    out = sys.stdout
    for line in sys.stdin:
        request = json.loads(line)
        os.chdir(request["cwd"])
        started = time.monotonic()
        result = run_one(request["argv"])
        result["seconds"] = time.monotonic() - started
        out.write({MARK!r} + json.dumps(result) + "\\n")
        out.flush()
    """
)


class CliServer:
    """One interpreter that runs command lines through ``sb3_hddpg.cli.main`` under the bounds."""

    def __init__(self, home: Path) -> None:
        self.home = home
        self.process: subprocess.Popen[str] | None = None

    def start(self) -> None:
        env = {
            **os.environ,
            "PYTHONPATH": str(REPO),
            "HOME": str(self.home),
            "SDL_VIDEODRIVER": "dummy",
            "COLUMNS": "200",
            "MPLCONFIGDIR": str(self.home.parent / "mpl"),  # matplotlib's cache is not the user's state here
        }
        self.process = subprocess.Popen(
            ["prlimit", f"--as={MEMORY_BOUND}", "--", sys.executable, "-c", SERVER],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
            cwd=REPO,
            env=env,
        )

    def run(self, argv: list[str], cwd: Path) -> dict[str, Any]:
        """The command's exit code, stdout, stderr and seconds; fails the test past the time bound."""
        if self.process is None or self.process.poll() is not None:
            self.start()
        process = self.process
        assert process is not None and process.stdin is not None and process.stdout is not None
        process.stdin.write(json.dumps({"argv": argv, "cwd": str(cwd)}) + "\n")
        process.stdin.flush()
        deadline = time.monotonic() + TIME_BOUND + 60  # the first command also pays the imports
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([process.stdout], [], [], left)[0]:
                self.stop()
                pytest.fail(f"hddpg-cli {argv!r} took longer than {TIME_BOUND:.0f} s (or hung)")
            line = process.stdout.readline()
            if not line:
                code = process.wait()
                self.process = None
                pytest.fail(f"hddpg-cli {argv!r} killed its interpreter (exit {code}): memory bound?")
            if line.startswith(MARK):
                return dict(json.loads(line[len(MARK) :]))

    def stop(self) -> None:
        if self.process is not None:
            self.process.kill()
            self.process.wait()
            self.process = None


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[CliServer]:
    home = tmp_path_factory.mktemp("fuzz") / "home"
    home.mkdir()
    cli = CliServer(home)
    yield cli
    cli.stop()


# ------------------------------------------------------------------------------------------- sandboxes
_COUNTER = itertools.count()


def make_sandbox(root: Path, home: Path) -> Path:
    """A fresh sandbox: the user's files in several places, an earlier run of the tool, inputs, outputs."""
    box = root / f"box{next(_COUNTER)}"
    for folder in ("cwd/data", "user/data", "inputs", "out"):
        (box / folder).mkdir(parents=True)
    for folder in ("cwd", "user"):
        (box / folder / "notes.txt").write_text("the user's")
        (box / folder / "data" / "x.csv").write_text("1,2\n")
    old = box / "oldrun"
    (old / "workers").mkdir(parents=True)
    (old / "workers" / "manifest.json").write_text("{}")
    (old / "hierarchy.zip").write_bytes(b"the tool's")
    (old / ".hddpg-run").write_text('{"tool": "sb3-hddpg", "command": "train-workers", "entries": []}')
    (old / "mine.txt").write_text("the user's, in a run folder")
    (box / "link").symlink_to(box / "user", target_is_directory=True)
    for stale in home.iterdir():  # an earlier example's failure is reported there, not here
        shutil.rmtree(stale) if stale.is_dir() else stale.unlink()
    return box


def files(folder: Path) -> dict[str, bytes]:
    """Every file below ``folder`` with its content (links are not followed)."""
    found = {}
    for top, _, names in os.walk(folder):
        for name in names:
            path = Path(top) / name
            if path.is_file() and not path.is_symlink():
                found[str(path.relative_to(folder))] = path.read_bytes()
    return found


USER_FILES = (
    "cwd/notes.txt",
    "cwd/data/x.csv",
    "user/notes.txt",
    "user/data/x.csv",
    "oldrun/mine.txt",
)


def check_invariants(
    box: Path, home: Path, argv: list[str], result: dict[str, Any], before: dict[str, bytes]
) -> None:
    """The properties every command keeps, whatever its input (see the module docstring)."""
    shown = f"hddpg-cli {' '.join(map(repr, argv))}"
    code, stderr = result["code"], result["stderr"]
    assert code in (0, 2), f"{shown}: exit {code}\n{stderr[-3000:]}"
    assert "Traceback" not in stderr, f"{shown}:\n{stderr[-3000:]}"
    if code == 2:
        lines = [line for line in stderr.splitlines() if line.strip()]
        assert len(lines) == 1 and lines[0].startswith("error:"), f"{shown}: stderr {stderr[-3000:]!r}"
    assert result["seconds"] < TIME_BOUND, f"{shown}: {result['seconds']:.0f} s"
    after = files(box)
    for name in USER_FILES:
        assert after.get(name) == before[name], f"{shown}: the user's {name} was deleted or changed"
    for name, content in before.items():
        if name.startswith("inputs/"):
            assert after.get(name) == content, f"{shown}: input {name} was changed"
    # An output the command may write into; never the sandbox, the current folder or anything above them.
    allowed = [a for a in (Path(box / p).resolve() for p in _outputs(argv)) if a not in (box, box / "cwd")]
    allowed = [a for a in allowed if box in a.parents]
    for name in set(after) - set(before):
        path = (box / name).resolve()
        assert any(path == a or a in path.parents for a in allowed), (
            f"{shown}: wrote {name} outside its --out"
        )
    assert not list(home.iterdir()), f"{shown}: wrote into the home folder: {list(home.iterdir())}"


def _outputs(argv: list[str]) -> list[str]:
    """
    Where ``argv`` may write, relative to the sandbox: its ``--out`` and ``--json``, export's DEST, and the
    SQLite file a ``--storage`` URL names (the user named each of them).
    """
    named = [argv[argv.index(flag) + 1] for flag in ("--out", "--json") if flag in argv[:-1]]
    if argv and argv[0] in ("export-models", "snapshot") and len(argv) > 2:
        named.append(argv[2])
    if "--storage" in argv[:-1] and argv[argv.index("--storage") + 1].startswith("sqlite:///"):
        database = argv[argv.index("--storage") + 1].removeprefix("sqlite:///").split("?")[0]
        named += [
            database + suffix for suffix in ("", "-wal", "-shm", "-journal", ".lock")
        ]  # and its claim lock
    if argv and argv[0] == "tune" and "--out" not in argv:
        named.append("runs")
    named = [value for value in named if "\x00" not in value]  # no path: the command must refuse it
    return [value if os.path.isabs(value) else str(Path("cwd") / value) for value in named]


def run_case(server: CliServer, tmp_path: Path, build: Callable[[Path], list[str]]) -> None:
    """Build a sandbox, let ``build`` write its inputs and return the command line, run it, check it."""
    box = make_sandbox(tmp_path, server.home)
    argv = build(box)
    before = files(box)
    result = server.run(argv, box / "cwd")
    check_invariants(box, server.home, argv, result, before)


# ------------------------------------------------------------------------------------------ strategies
HOSTILE_TEXT = st.one_of(
    st.sampled_from(
        [
            "é",
            "..",
            ".",
            "../x",
            "a/b",
            "-x",
            "_x",
            "a" * 65,
            "a" * 300,
            "goal\n",
            " ",
            "\u00b2",
            "\u0663",
            "ｇｏａｌ",
            "a\x00b",
            "$(touch pwned)",
            "`id`",
            "%s%n",
            "~",
            "/",
            "CON",
            "nul",
            "a:b",
            "*",
        ]
    ),
    st.text(min_size=0, max_size=70),
    st.text(alphabet="abcdefgh_-0123456789.", min_size=1, max_size=12),
)

#: ``--out`` values: the places that must never be cleared, the user's and the tool's folders, new names.
OUT_PATHS = st.one_of(
    st.sampled_from(
        [".", "..", "", "../user", "../oldrun", "../link", "../inputs", "/", "~", "../../..", "data"]
    ),
    HOSTILE_TEXT.map(lambda name: f"../out/{name}"),
    HOSTILE_TEXT.map(lambda name: f"new-{name}"),
)


def _zip(members: list[tuple[str, bytes]]) -> bytes:
    buffer = io.BytesIO()
    with warnings.catch_warnings(), zipfile.ZipFile(buffer, "w") as archive:
        warnings.simplefilter("ignore")  # duplicate member names are part of the fuzzing
        for name, data in members:
            archive.writestr(name, data)
    return buffer.getvalue()


JSON_VALUES = st.recursive(
    st.one_of(
        st.none(), st.booleans(), st.integers(-(10**30), 10**30), st.floats(allow_nan=True), HOSTILE_TEXT
    ),
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(HOSTILE_TEXT, inner, max_size=4)),
    max_leaves=12,
)
MANIFEST_KEYS = (
    "schema",
    "workers",
    "manager",
    "env_id",
    "env_kwargs",
    "selection",
    "name",
    "algo",
    "file",
    "sha256",
)
MANIFESTS = st.dictionaries(st.sampled_from(MANIFEST_KEYS) | HOSTILE_TEXT, JSON_VALUES, max_size=8)
MEMBER_NAMES = st.one_of(
    st.sampled_from(
        [
            "manifest.json",
            "manager.zip",
            "workers/goal.zip",
            "../evil.zip",
            "/abs.zip",
            "workers/../../x.zip",
            "data",
        ]
    ),
    HOSTILE_TEXT.filter(lambda name: name != ""),
)
BUNDLES = st.lists(
    st.tuples(
        MEMBER_NAMES, st.one_of(st.binary(max_size=64), MANIFESTS.map(lambda m: json.dumps(m).encode()))
    ),
    max_size=5,
).map(_zip)


def _write_bundle(box: Path, data: bytes) -> str:
    (box / "inputs" / "bundle.zip").write_bytes(data)
    return str(box / "inputs" / "bundle.zip")


MODELS = st.one_of(
    BUNDLES.map(lambda data: ("bundle", data)),
    st.sampled_from(["missing", "folder", "devnull", "worker"]).map(lambda kind: (kind, b"")),
)


def _model_path(box: Path, model: tuple[str, bytes]) -> str:
    kind, data = model
    if kind == "bundle":
        return _write_bundle(box, data)
    return {
        "missing": str(box / "inputs" / "missing.zip"),
        "folder": str(box / "inputs"),
        "devnull": "/dev/null",
        "worker": str(WORKER),
    }[kind]


_SETTINGS = {
    "deadline": None,
    "suppress_health_check": [HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
}


def fuzz(
    strategy: st.SearchStrategy[Any], long: st.SearchStrategy[Any] | None = None
) -> Callable[[Callable[..., None]], Any]:
    """
    The property as a short test of the default run (:data:`FAST_EXAMPLES`, derandomised so that CI runs
    the same examples each time); :func:`long_twin` makes its ``-m slow`` twin from the same body, drawing
    from ``long`` when given (cases too costly for the short run, e.g. a valid storage that runs a trial).
    """

    def decorate(body: Callable[..., None]) -> Any:
        test = settings(max_examples=FAST_EXAMPLES, derandomize=True, **_SETTINGS)(given(case=strategy)(body))
        test.fuzz_body, test.fuzz_strategy = body, long if long is not None else strategy
        return test

    return decorate


def long_twin(test: Any) -> Any:
    """The same property with :data:`LONG_EXAMPLES` random examples, for ``-m slow``."""
    body = test.fuzz_body

    @pytest.mark.slow
    @pytest.mark.timeout(LONG_EXAMPLES * TIME_BOUND)
    @settings(max_examples=LONG_EXAMPLES, **_SETTINGS)
    @given(case=test.fuzz_strategy)
    def twin(server: CliServer, tmp_path: Path, case: Any) -> None:
        body(server, tmp_path, case)

    return twin


# ------------------------------------------------------------------------------------------ properties
@fuzz(st.tuples(MODELS, OUT_PATHS, st.booleans()))
def test_package_keeps_the_invariants(server, tmp_path, case):
    model, out, force = case
    run_case(
        server,
        tmp_path,
        lambda box: [
            "package",
            _model_path(box, model),
            "--out",
            out,
            "--episodes",
            "1",
            "--video-steps",
            "2",
            *(["--force"] if force else []),
        ],
    )


@fuzz(st.tuples(OUT_PATHS, st.booleans(), st.sampled_from(["goal", "avoid"])))
def test_train_workers_force_keeps_the_invariants(server, tmp_path, case):
    out, force, worker = case
    argv = [
        "train-workers",
        "--worker",
        worker,
        "--timesteps",
        "8",
        "--eval-freq",
        "0",
        "--checkpoint-freq",
        "0",
    ]
    argv += ["--no-progress", "--out", out, *(["--force"] if force else [])]
    run_case(server, tmp_path, lambda box: argv)


RECORDS = st.fixed_dictionaries(
    {
        "status": st.sampled_from(["done", "done", "running"]) | HOSTILE_TEXT,
        "method": st.sampled_from(["workers", "hddpg", "ham", "ddpg", "hddpg@goal"]) | HOSTILE_TEXT,
        "seed": st.one_of(st.integers(-5, 2**40), HOSTILE_TEXT, st.floats(allow_nan=True), st.booleans()),
        "workers": st.one_of(
            st.lists(HOSTILE_TEXT, max_size=3), st.dictionaries(HOSTILE_TEXT, JSON_VALUES, max_size=3)
        ),
    }
)


@fuzz(st.tuples(st.lists(RECORDS, min_size=1, max_size=3), OUT_PATHS))
def test_export_models_keeps_the_invariants(server, tmp_path, case):
    records, dest = case

    def build(box: Path) -> list[str]:
        for i, record in enumerate(records):
            folder = box / "inputs" / "bench" / "records" / f"m{i}"
            folder.mkdir(parents=True)
            (folder / "seed-0.json").write_text(json.dumps(record))
        return ["export-models", str(box / "inputs" / "bench"), dest]

    run_case(server, tmp_path, build)


SETTINGS = st.one_of(
    st.just({"methods": ["ham"], "seeds": [0]}),
    st.fixed_dictionaries(
        {
            "methods": st.lists(st.sampled_from(["ham", "hddpg"]) | HOSTILE_TEXT, max_size=2),
            "seeds": JSON_VALUES,
        }
    ),
    JSON_VALUES,
)


@fuzz(st.tuples(SETTINGS, st.lists(RECORDS, min_size=1, max_size=3), JSON_VALUES, OUT_PATHS))
def test_snapshot_keeps_the_invariants(server, tmp_path, case):
    settings, records, invocations, dest = case

    def build(box: Path) -> list[str]:
        bench = box / "inputs" / "bench"
        bench.mkdir(parents=True)
        (bench / "benchmark.json").write_text(json.dumps({"settings": settings, "invocations": invocations}))
        # Where the settings' runs keep their records first, then elsewhere.
        for name, record in zip(("workers", "ham", "other"), records, strict=False):
            (bench / "records" / name).mkdir(parents=True)
            (bench / "records" / name / "seed-0.json").write_text(json.dumps(record))
        return ["snapshot", str(bench), dest]

    run_case(server, tmp_path, build)


@fuzz(st.tuples(MODELS, st.integers(-3, 2), HOSTILE_TEXT))
def test_evaluate_keeps_the_invariants(server, tmp_path, case):
    model, episodes, json_name = case
    run_case(
        server,
        tmp_path,
        lambda box: [
            "evaluate",
            _model_path(box, model),
            "--episodes",
            str(episodes),
            "--json",
            f"../out/{json_name}",
        ],
    )


@fuzz(st.tuples(MANIFESTS, st.lists(st.tuples(HOSTILE_TEXT, st.binary(max_size=32)), max_size=3), OUT_PATHS))
def test_train_manager_with_hostile_workers_keeps_the_invariants(server, tmp_path, case):
    manifest, extra, out = case

    def build(box: Path) -> list[str]:
        workers = box / "inputs" / "workers"
        workers.mkdir()
        (workers / "manifest.json").write_text(json.dumps(manifest))
        for name, data in extra:
            if name and "/" not in name and "\x00" not in name and name not in (".", ".."):
                (workers / name[:100]).write_bytes(data)
        return ["train-manager", "--workers", str(workers), "--timesteps", "8", "--no-progress", "--out", out]

    run_case(server, tmp_path, build)


TERM_SPECS = st.one_of(
    HOSTILE_TEXT,
    st.lists(HOSTILE_TEXT, min_size=1, max_size=4).map(",".join),
    st.sampled_from(["obj0,obj1", "speed,energy", "a,a", "", ","]),
)
TERM_BOUNDS = st.one_of(
    st.none(),
    HOSTILE_TEXT,
    st.tuples(HOSTILE_TEXT, st.floats(), st.floats()).map(lambda t: f"{t[0]}={t[1]}:{t[2]}"),
)


@fuzz(st.tuples(TERM_SPECS, TERM_BOUNDS, OUT_PATHS))
def test_term_specs_keep_the_invariants(server, tmp_path, case):
    terms, bounds, out = case
    argv = ["train-workers", "--env", "mo-mountaincarcontinuous-v0", "--terms", terms]
    argv += ["--term-bounds", bounds] if bounds is not None else []
    argv += ["--timesteps", "8", "--eval-freq", "0", "--checkpoint-freq", "0", "--no-progress", "--out", out]
    run_case(server, tmp_path, lambda box: argv)


ADDRESSES = st.one_of(
    HOSTILE_TEXT,
    st.sampled_from(
        ["127.0.0.1:1", "127.0.0.1:\u00b2", "127.0.0.1:99999", "[::1]:1", "ray://127.0.0.1:1", "h:0"]
    ),
    st.tuples(HOSTILE_TEXT, st.integers(-1, 70000)).map(lambda t: f"{t[0]}:{t[1]}"),
)
STORAGES = st.one_of(
    HOSTILE_TEXT,  # no scheme: refused before any trial
    st.sampled_from(
        [
            "sqlite:///file::memory:?uri=true",
            "sqlite:////dev/null",
            "sqlite:///../inputs",
            "sqlite://",
            "postgresql+psycopg://u:pw@127.0.0.1:1/db",
            "postgresql+psycopg://u:pw@127.0.0.1:1/db?sslmode=bogus",
            "mysql://x",
            "nosuchdb://x",
        ]
    ),
)
#: The long run adds SQLite files at hostile paths: a valid one runs a trial (a process, seconds).
STORAGES_LONG = STORAGES | HOSTILE_TEXT.map(lambda path: f"sqlite:///{path}")


@fuzz(st.tuples(ADDRESSES, OUT_PATHS))
def test_ray_addresses_keep_the_invariants(server, tmp_path, case):
    address, out = case
    if address.strip() in ("auto", ""):  # a cluster of this machine is the user's, not the fuzzer's
        address = "127.0.0.1:1"
    argv = ["benchmark", "--executor", "ray", "--ray-address", address, "--out", out]
    run_case(server, tmp_path, lambda box: argv)


@fuzz(st.tuples(STORAGES, OUT_PATHS), long=st.tuples(STORAGES_LONG, OUT_PATHS))
def test_storage_urls_keep_the_invariants(server, tmp_path, case):
    url, out = case
    argv = ["tune", "--level", "worker", "--worker", "goal", "--n-trials", "1", "--timesteps", "8"]
    argv += ["--n-evaluations", "1", "--eval-episodes", "1", "--storage", url, "--out", out]
    run_case(server, tmp_path, lambda box: argv)


test_package_keeps_the_invariants_long = long_twin(test_package_keeps_the_invariants)
test_train_workers_force_keeps_the_invariants_long = long_twin(test_train_workers_force_keeps_the_invariants)
test_export_models_keeps_the_invariants_long = long_twin(test_export_models_keeps_the_invariants)
test_snapshot_keeps_the_invariants_long = long_twin(test_snapshot_keeps_the_invariants)
test_evaluate_keeps_the_invariants_long = long_twin(test_evaluate_keeps_the_invariants)
test_train_manager_with_hostile_workers_keeps_the_invariants_long = long_twin(
    test_train_manager_with_hostile_workers_keeps_the_invariants
)
test_term_specs_keep_the_invariants_long = long_twin(test_term_specs_keep_the_invariants)
test_ray_addresses_keep_the_invariants_long = long_twin(test_ray_addresses_keep_the_invariants)
test_storage_urls_keep_the_invariants_long = long_twin(test_storage_urls_keep_the_invariants)

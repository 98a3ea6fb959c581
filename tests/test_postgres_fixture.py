"""The throw-away PostgreSQL server: an Optuna study shared by two processes, then a clean shutdown."""

import multiprocessing
import socket
from urllib.parse import urlsplit

import optuna
from postgres_server import running_postgres

STUDY_NAME = "postgres-fixture-test"
TRIALS_PER_PROCESS = 3


def objective(trial: optuna.Trial) -> float:
    x = trial.suggest_float("x", -1.0, 1.0)
    return x * x


def optimise(url: str) -> None:
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.load_study(study_name=STUDY_NAME, storage=url)
    study.optimize(objective, n_trials=TRIALS_PER_PROCESS)


def test_optuna_study_shared_by_two_processes(tmp_path):
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    with running_postgres(tmp_path) as url:
        port = urlsplit(url).port
        assert url.startswith("postgresql+psycopg://")
        assert urlsplit(url).hostname == "127.0.0.1"
        storage = optuna.storages.RDBStorage(url)
        optuna.create_study(storage=storage, study_name=STUDY_NAME)
        # spawn, not fork: a forked child would share the parent's pooled database connections.
        context = multiprocessing.get_context("spawn")
        workers = [context.Process(target=optimise, args=(url,)) for _ in range(2)]
        for worker in workers:
            worker.start()
        for worker in workers:
            worker.join(timeout=300)
        assert [worker.exitcode for worker in workers] == [0, 0]

        study = optuna.load_study(study_name=STUDY_NAME, storage=storage)
        finished = study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))
        assert len(finished) == 2 * TRIALS_PER_PROCESS
        assert len(study.trials) == 2 * TRIALS_PER_PROCESS
        assert sorted(trial.number for trial in finished) == list(range(2 * TRIALS_PER_PROCESS))
        storage.engine.dispose()

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.settimeout(2.0)
        assert sock.connect_ex(("127.0.0.1", port)) != 0, "server still accepts connections after exit"
    assert (tmp_path / "postgres.log").exists()

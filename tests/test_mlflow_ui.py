"""The MLflow UI in a real browser, over the runs a tiny `dvc repro` logs to its default SQLite store.

What a user does after `make pipeline`: start `mlflow server` over `mlflow.db`, open the
experiment's runs (its "Model training" view), see one run per stage, open a run and read
its metrics. The MLflow UI is a React app that renders after the page loads, so every check is
a Playwright `expect`, which waits for the element. The screenshots the README shows
(`reports/mlflow_ui.png`, `reports/mlflow_ui_run.png`) are written only once the checks have
seen the runs.

Playwright drives Debian's Chromium (`make system-deps`), never a browser of its own:
nothing is downloaded, so `playwright install` is neither needed nor possible here.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import mlflow
import pytest
from playwright.sync_api import Browser, Page, expect, sync_playwright

from tests.project import REPOSITORY
from tests.servers import INSTALL_HINT, mlflow_server

pytestmark = pytest.mark.slow

CHROMIUM = Path("/usr/bin/chromium")
# Headless; no sandbox, which Chromium cannot set up as root (CI); and nothing that reaches out
# to the network on its own (updates, sync, QUIC probes).
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
EXPERIMENT = "radar-nn-tracker"
STAGE_RUNS = ("train_filter", "train_predictor", "train_autoencoder", "evaluate")
SCREENSHOTS = REPOSITORY / "reports"


@pytest.fixture(scope="module")
def server_url(tiny_pipeline: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """`mlflow server` over the store the tiny pipeline run filled, as the README says to start it."""
    with mlflow_server(f"sqlite:///{tiny_pipeline / 'mlflow.db'}", tmp_path_factory.mktemp("mlflow-ui")) as url:
        yield url


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    if not CHROMIUM.is_file():
        pytest.fail(f"Chromium is not installed ({CHROMIUM} is missing): {INSTALL_HINT}, "
                    "or `apt-get install -y --no-install-recommends chromium`")
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        yield browser
        browser.close()


@pytest.fixture
def page(browser: Browser) -> Iterator[Page]:
    context = browser.new_context(viewport={"width": 1400, "height": 760})
    yield context.new_page()
    context.close()


def model_training_page(server_url: str, route: str) -> str:
    """The address of a UI page in its "Model training" view. MLflow 3 shows an experiment
    that has no kind in its GenAI view, without the runs table."""
    return f"{server_url}/#/{route}?workflowType=machine_learning"


def experiment_id(server_url: str) -> str:
    experiment = mlflow.MlflowClient(tracking_uri=server_url).get_experiment_by_name(EXPERIMENT)
    assert experiment is not None, f"no experiment {EXPERIMENT!r} on {server_url}"
    return experiment.experiment_id


def close_assistant(page: Page) -> None:
    """The MLflow Assistant panel takes a third of the screen; the screenshots are better without it."""
    close = page.get_by_role("button", name="Close", exact=True)
    if close.is_visible():
        close.click()
        expect(close).to_be_hidden()


def test_experiment_page_lists_every_stage_run(page: Page, server_url: str) -> None:
    page.goto(model_training_page(server_url, f"experiments/{experiment_id(server_url)}/runs"))
    for name in STAGE_RUNS:
        expect(page.get_by_role("link", name=name, exact=True)).to_be_visible()
    close_assistant(page)
    page.screenshot(path=SCREENSHOTS / "mlflow_ui.png")


def test_run_page_shows_its_metrics(page: Page, server_url: str) -> None:
    """The train_filter run's hold-out metrics, with the values the tracking API returns."""
    experiment = experiment_id(server_url)
    client = mlflow.MlflowClient(tracking_uri=server_url)
    [run] = client.search_runs([experiment], "attributes.run_name = 'train_filter'")
    page.goto(model_training_page(server_url, f"experiments/{experiment}/runs/{run.info.run_id}"))
    expect(page.get_by_text(run.info.run_id)).to_be_visible()
    for metric in ("filter_error_m", "raw_plot_error_m", "kalman_cv_error_m", "val_loss"):
        row = page.get_by_role("row").filter(has=page.get_by_role("link", name=metric, exact=True))
        # The UI prints the shortest repr of a double, as Python's repr does.
        expect(row).to_contain_text(repr(run.data.metrics[metric]))
    close_assistant(page)
    page.screenshot(path=SCREENSHOTS / "mlflow_ui_run.png")

"""The MLflow UI in a real browser, over the runs a tiny `dvc repro` and a queued sweep log to the
default SQLite store.

What a user does after `make pipeline` and the sweep of docs/networks.md: start `mlflow server` over
`mlflow.db`, open the address the README gives (the experiment's runs table), see one run per
stage, open a run and read its metrics, open the Models page and find
the three networks. The MLflow UI is a React app that renders after the page loads, so every
check is a Playwright `expect`, which waits for the element. The screenshots docs/networks.md and docs/team.md show
(`reports/mlflow_ui.png`, `reports/mlflow_ui_run.png`, `reports/mlflow_ui_models.png`) are
written only once the checks have seen what they show. What the runs record beyond the UI (the
model versions an evaluate run used, the span of a run) is checked through the tracking API.

Playwright drives Debian's Chromium (`make system-deps`), never a browser of its own:
nothing is downloaded, so `playwright install` is neither needed nor possible here.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import mlflow
import pytest
import yaml
from playwright.sync_api import Browser, Page, expect, sync_playwright

from pipeline import io
from pipeline.learning.experiment_tracking import DVC_EXPERIMENT_TAG, SESSION_TAG, data_hash
from pipeline.learning.mlflow_models import FILE_DIGEST_TAG, registered_name
from pipeline.learning.networks import KINDS
from tests.project import REPOSITORY
from tests.servers import INSTALL_HINT, mlflow_server

pytestmark = pytest.mark.slow

CHROMIUM = Path("/usr/bin/chromium")
# Headless; no sandbox, which Chromium cannot set up as root (CI); and nothing that reaches out
# to the network on its own (updates, sync, QUIC probes).
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
EXPERIMENT = "radar-nn-tracker"
STAGE_RUNS = ("train_filter", "train_predictor", "train_autoencoder", "tune_kalman", "evaluate")
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


def ui_page(server_url: str, route: str) -> str:
    """The address of a UI page in its "Machine learning" view. MLflow 3.17's UI picks the view
    from the address or from what the browser last chose, never from the experiment's kind tag,
    and starts a new browser on the GenAI view ("Model training" at the top left is the other), which has
    neither a runs table nor the Models page."""
    return f"{server_url}/#/{route}?workflowType=machine_learning"


def readme_address() -> str:
    """The address the README's walkthrough tells a newcomer to open, after the server's."""
    readme = (REPOSITORY / "README.md").read_text()
    match = re.search(r"^mlflow ui .*# open http://127\.0\.0\.1:5000(/[^\s,]+)", readme, re.MULTILINE)
    assert match, "the README's walkthrough gives no address to open after `mlflow ui`"
    return match.group(1)


def experiment_id(server_url: str) -> str:
    experiment = mlflow.MlflowClient(tracking_uri=server_url).get_experiment_by_name(EXPERIMENT)
    assert experiment is not None, f"no experiment {EXPERIMENT!r} on {server_url}"
    return experiment.experiment_id


def close_assistant(page: Page) -> None:
    """The MLflow Assistant panel takes a third of the screen, and MLflow's announcements open as
    dialogs over the page; the screenshots are better without them. Dialogs first: they take
    the clicks meant for the page under them."""
    for dialog in page.get_by_role("dialog").all():
        if dialog.is_visible():
            dialog.get_by_role("button", name=re.compile(r"^Close")).first.click()
            expect(dialog).to_be_hidden()
    close = page.get_by_role("button", name="Close", exact=True)
    if close.is_visible():
        close.click()
        expect(close).to_be_hidden()


def test_the_readmes_address_opens_the_runs_table_listing_every_stage_run(page: Page, server_url: str) -> None:
    """The address the README gives, in a browser that never opened MLflow, shows the
    experiment's runs table with one run per stage (the sweep's two train_predictor runs too)."""
    assert readme_address() == f"/#/experiments/{experiment_id(server_url)}?workflowType=machine_learning"
    page.goto(server_url + readme_address())
    expect(page).to_have_url(re.compile(r"/experiments/\d+/runs\b"))
    for name in STAGE_RUNS:
        expect(page.get_by_role("link", name=name, exact=True).first).to_be_visible()
    expect(page.get_by_role("link", name="train_predictor", exact=True)).to_have_count(3)
    close_assistant(page)
    page.screenshot(path=SCREENSHOTS / "mlflow_ui.png")


def test_run_page_shows_its_metrics(page: Page, server_url: str) -> None:
    """The train_filter run's hold-out metrics, with the values the tracking API returns."""
    experiment = experiment_id(server_url)
    client = mlflow.MlflowClient(tracking_uri=server_url)
    [run] = client.search_runs([experiment], "attributes.run_name = 'train_filter'")
    page.goto(ui_page(server_url, f"experiments/{experiment}/runs/{run.info.run_id}"))
    expect(page.get_by_text(run.info.run_id)).to_be_visible()
    for metric in ("filter_error_m", "raw_plot_error_m", "kalman_cv_error_m", "val_loss"):
        row = page.get_by_role("row").filter(has=page.get_by_role("link", name=metric, exact=True))
        # The UI prints the shortest repr of a double, as Python's repr does.
        expect(row).to_contain_text(repr(run.data.metrics[metric]))
    close_assistant(page)
    page.screenshot(path=SCREENSHOTS / "mlflow_ui_run.png")


def test_models_page_lists_the_three_networks(page: Page, server_url: str) -> None:
    """The Models page (the Model Registry) has one registered model per network, the
    predictor with the sweep's versions beside the first run's."""
    page.goto(ui_page(server_url, "models"))
    for kind in KINDS:
        expect(page.get_by_role("link", name=registered_name(EXPERIMENT, kind), exact=True)).to_be_visible()
    expect(page.get_by_role("row").filter(
        has=page.get_by_role("link", name=registered_name(EXPERIMENT, "predictor"), exact=True))).to_contain_text(
        "Version 3")
    close_assistant(page)
    page.screenshot(path=SCREENSHOTS / "mlflow_ui_models.png")


def test_the_sweeps_runs_and_versions_carry_their_dvc_experiment(server_url: str) -> None:
    """Each queued experiment of the sweep logged a train_predictor run and a predictor version,
    both tagged with DVC's experiment name, which is also the run's session; the runs of the
    plain `dvc repro` share one session of their own."""
    client = mlflow.MlflowClient(tracking_uri=server_url)
    runs = client.search_runs([experiment_id(server_url)])
    swept = [run for run in runs if DVC_EXPERIMENT_TAG in run.data.tags]
    assert [run.info.run_name for run in swept] == ["train_predictor", "train_predictor"]
    assert all(run.data.tags[SESSION_TAG] == run.data.tags[DVC_EXPERIMENT_TAG] for run in swept)
    assert len({run.data.tags[SESSION_TAG] for run in swept}) == 2
    assert len({run.data.tags[SESSION_TAG] for run in runs if run not in swept}) == 1
    versions = client.search_model_versions(f"name = '{registered_name(EXPERIMENT, 'predictor')}'")
    assert {version.run_id: version.tags.get(DVC_EXPERIMENT_TAG) for version in versions if
            version.run_id in {run.info.run_id for run in swept}} == {
        run.info.run_id: run.data.tags[DVC_EXPERIMENT_TAG] for run in swept}


def test_the_evaluate_run_names_the_model_versions_it_used(server_url: str, tiny_pipeline: Path) -> None:
    """The evaluate run's tags name, for each network, the registered version whose bundle the
    tracker loaded (not the sweep's later predictor versions), and link the logged models."""
    client = mlflow.MlflowClient(tracking_uri=server_url)
    [run] = client.search_runs([experiment_id(server_url)], "attributes.run_name = 'evaluate'")
    for kind in KINDS:
        name = registered_name(EXPERIMENT, kind)
        version = client.get_model_version(name, run.data.tags[f"model.{kind}.version"])
        assert version.tags[FILE_DIGEST_TAG] == data_hash(tiny_pipeline / "models" / f"{kind}.pt")
        assert run.data.tags[f"model.{kind}.uri"] == f"models:/{name}/{version.version}"
    predictors = client.search_model_versions(f"name = '{registered_name(EXPERIMENT, 'predictor')}'")
    assert sorted(int(version.version) for version in predictors) == [1, 2, 3]
    assert run.data.tags["model.predictor.version"] == "1"
    assert len(client.get_run(run.info.run_id).inputs.model_inputs) == len(KINDS)


def work_seconds(repository: Path, stage: str) -> float:
    """A lower bound of the seconds the stage's work took, from what its report measured: the
    longest filter's tuning, or the tracking time of every run spread over the worker processes."""
    if stage == "tune_kalman":
        filters = io.read_metrics(repository / "reports" / "kalman_tuning.json")["filters"]
        return max(entry["seconds"] for entry in filters.values())
    runs = io.read_metrics(repository / "reports" / "tracker_metrics.json")["runs"]
    workers = yaml.safe_load((repository / "params.yaml").read_text())["compute"]["workers"]
    return sum((run["target_plots"] + run["false_plots"]) / run["plots_per_second"] for run in runs.values()) / workers


@pytest.mark.parametrize("stage", ["tune_kalman", "evaluate"])
def test_a_stages_run_spans_its_work(server_url: str, tiny_pipeline: Path, stage: str) -> None:
    """The run opens before the stage's work and closes after it, so the duration the UI shows
    is the stage's (it was 0.1 s when the run was opened to log what the work had done)."""
    client = mlflow.MlflowClient(tracking_uri=server_url)
    [run] = client.search_runs([experiment_id(server_url)], f"attributes.run_name = '{stage}'")
    assert (run.info.end_time - run.info.start_time) / 1000.0 >= work_seconds(tiny_pipeline, stage) > 1.0

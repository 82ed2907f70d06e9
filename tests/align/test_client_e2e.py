"""The Python clients (sync and async) and ``itnet-align --server`` against a real ``itnet serve``
process on 127.0.0.1, with the tiny random model."""

import asyncio
import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from benchmarks.harness import serve
from itnet.cli import align_app
from itnet.clients import AsyncItnetClient, ItnetClient, ItnetRequestError

pytestmark = pytest.mark.e2e
EXAMPLES = Path(__file__).resolve().parents[2] / "itnet" / "examples"


@pytest.fixture(scope="module")
def server(tiny_model_dir, tmp_path_factory):
    """URL of an ``itnet serve`` subprocess (stopped after the module; 30 s to come up)."""
    log = tmp_path_factory.mktemp("align-e2e") / "server.log"
    with serve(tiny_model_dir, log, timeout_s=30) as running:
        yield running.url


@pytest.fixture
def cloud(rng):
    return rng.normal(size=(400, 3)) * [0.4, 0.3, 0.2] + [0.5, -0.2, 2.5]


def test_json_and_binary_posts_agree(server, cloud):
    with ItnetClient(server) as client:
        as_json = client.estimate(cloud, model="tiny", budget_ms=1000, max_iterations=4)
        as_binary = client.estimate(cloud, model="tiny", budget_ms=1000, max_iterations=4,
                                    binary=True)  # fmt: skip
    assert as_json.iterations == as_binary.iterations == 4
    assert as_json.stopped_by == "max_iterations" and as_json.model == "tiny"
    assert [e.iteration for e in as_json.estimates] == [1, 2, 3, 4]
    assert np.allclose(as_json.estimates[-1].T_canonical_from_input, as_json.T_canonical_from_input)
    # float32 on the wire: the same pose up to float32 rounding of the input.
    assert np.allclose(as_json.T_canonical_from_input, as_binary.T_canonical_from_input, atol=1e-4)


def test_stream_yields_every_iteration_then_the_result(server, cloud):
    with ItnetClient(server) as client:
        posted = client.estimate(cloud, model="tiny", budget_ms=1000, max_iterations=5)
        with client.stream(cloud, model="tiny", budget_ms=1000, max_iterations=5) as stream:
            iterations = [e.iteration for e in stream]
        with client.stream(cloud, model="tiny", budget_ms=5_000, max_iterations=2,
                           ensemble=3, verify=False) as fused:  # fmt: skip
            assert [e.iteration for e in fused] == [1, 2]
    assert (fused.result.ensemble, fused.result.verified) == (3, None)
    assert iterations == [1, 2, 3, 4, 5]
    result = stream.result
    assert result is not None and result.stopped_by == "max_iterations"
    assert len(result.estimates) == 5
    assert np.allclose(result.T_canonical_from_input, posted.T_canonical_from_input, atol=1e-9)


def test_stream_cancel_returns_the_best_so_far(server, cloud):
    with ItnetClient(server) as client:
        stream = client.stream(cloud, model="tiny", budget_ms=5_000, max_iterations=200)
        seen = []
        for estimate in stream:
            seen.append(estimate)
            if estimate.iteration == 2:
                stream.cancel()
    assert stream.result.stopped_by == "cancelled"
    assert 2 <= stream.result.iterations < 200
    assert np.allclose(stream.result.T_canonical_from_input, seen[-1].T_canonical_from_input)


def test_refusals_raise_with_the_service_message(server, cloud):
    with ItnetClient(server) as client:
        with pytest.raises(ItnetRequestError, match="too few") as info:
            client.estimate(cloud[:5], model="tiny")
        assert info.value.status == 422
        with pytest.raises(ItnetRequestError) as info:
            client.estimate(cloud, model="no-such-model", binary=True)
        assert info.value.status == 404
        with pytest.raises(ItnetRequestError, match="too few"):
            list(client.stream(cloud[:5], model="tiny"))
        capped = client.estimate(cloud, model="tiny", max_iterations=1, budget_ms=5_000)
        assert capped.iterations == 1  # the cap, not the clock (a loaded machine is slow)
        for binary in (False, True):  # the field reaches the service either way
            with pytest.raises(ItnetRequestError, match="declares no mirror symmetry"):
                client.estimate(cloud, model="tiny", mirror=True, binary=binary)
        plain = client.estimate(cloud, model="tiny", mirror=False, binary=True, budget_ms=5_000)
        assert "mirror" not in plain.raw


def test_async_client(server, cloud):
    async def main():
        async with AsyncItnetClient(server) as client:
            posted = await client.estimate(
                cloud, model="tiny", max_iterations=3, binary=True, budget_ms=5_000
            )
            stream = await client.stream(cloud, model="tiny", max_iterations=3, budget_ms=5_000)
            async with stream:
                iterations = [e.iteration async for e in stream]
            fused = await client.stream(cloud, model="tiny", max_iterations=2, budget_ms=5_000,
                                        ensemble=2, verify=True)  # fmt: skip
            async with fused:
                assert [e.iteration async for e in fused] == [1, 2]
            assert (fused.result.ensemble, fused.result.verified) == (2, True)
            with pytest.raises(ItnetRequestError):
                await client.estimate(cloud[:5], model="tiny")
            return posted, iterations, stream.result

    posted, iterations, result = asyncio.run(main())
    assert posted.iterations == 3 and iterations == [1, 2, 3]
    assert np.allclose(result.T_canonical_from_input, posted.T_canonical_from_input, atol=1e-4)


def test_align_through_the_server_matches_in_process(server, tiny_model_dir):
    runner = CliRunner()
    files = [str(EXAMPLES / "chair_a.ply"), str(EXAMPLES / "chair_b.ply"), "--json",
             "--model", "tiny", "--no-refine", "--budget-ms", "5000",
             "--max-iterations", "3"]  # IT-Net's poses alone, by the cap: the wire's part  # fmt: skip
    remote = runner.invoke(align_app, [*files, "--server", server])
    local = runner.invoke(align_app, [*files, "--model-dir", str(tiny_model_dir)])
    assert remote.exit_code == local.exit_code == 0, remote.output + local.output
    remote_t = np.array(json.loads(remote.stdout)["T_b_from_a"])
    local_t = np.array(json.loads(local.stdout)["T_b_from_a"])
    assert np.allclose(remote_t, local_t, atol=1e-4)  # float32 binary body on the wire
    assert json.loads(remote.stdout)["hypothesis"] == json.loads(local.stdout)["hypothesis"]
    down = runner.invoke(align_app, [*files, "--server", "http://127.0.0.1:9"])
    assert down.exit_code == 1 and "127.0.0.1:9" in down.stderr

import pytest


@pytest.fixture(scope="session")
def tiny_bench(tmp_path_factory):
    """`lfusd bench make tiny`, run once for the session: (exit code, benchmark folder)."""
    from lfusd.cli import main

    out = tmp_path_factory.mktemp("bench") / "tiny"
    code = main(["bench", "make", "tiny", "-o", str(out), "--quiet"])
    return code, out

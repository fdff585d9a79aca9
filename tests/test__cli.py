"""cardiosoft._cli, the commands' shared plumbing: the XLA flags a command's process sets
(the rest of it is tested through the commands: test_cli_cache.py, test_cli_exit_status.py)."""

from cardiosoft._cli import xla_flags


def test_xla_flags_fast_compiles_where_compiling_dominates_and_keeps_a_users_own():
    """The main job and the design searches compile at XLA's optimisation level 0; a command
    with --uncertainty, whose time is solving the posterior's draws (3.5x slower at level 0,
    compiled no faster: cardiosoft._cli.SOLVES_MORE_THAN_COMPILES), keeps XLA's settings; so
    does any command given an XLA_FLAGS of the user's own; a sweep gets one device a core."""
    level_0 = "--xla_backend_optimization_level=0"
    assert level_0 in xla_flags("simulate", ["--bpm", "60"], None)
    assert level_0 in xla_flags("design", ["--target-sv", "70"], None)
    assert xla_flags("simulate", ["--bpm", "60", "--uncertainty"], None) is None
    assert xla_flags("design", ["--target-sv", "70", "--uncertainty"], None) is None
    assert xla_flags("simulate", ["--bpm", "60"], "--xla_dump_to=/tmp") is None
    assert "xla_force_host_platform_device_count" in xla_flags("sweep", [], "")
    assert xla_flags("sweep", ["--workers", "2"], None) is None

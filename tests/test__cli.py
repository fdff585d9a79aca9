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


def test_xla_flags_keep_xlas_settings_for_a_closed_loops_design(tmp_path):
    """A closed loop's design shoots to its orbit some 50 times: its time is solving (tah warm
    34.6 s at level 0 against 14.8 s at XLA's settings; see
    cardiosoft._cli.solves_more_than_compiles), so it keeps XLA's settings, for a shipped loop
    and a loop's own .toml file alike; a pump scene's design and a closed loop's simulate
    still compile fast."""
    level_0 = "--xla_backend_optimization_level=0"
    assert xla_flags("design", ["--scene", "tah", "--target-co", "5"], None) is None
    assert xla_flags("design", ["--scene=soft-lv", "--target-co", "4.5"], None) is None
    own = tmp_path / "my-loop.toml"
    own.write_text(_shipped_text("soft-rv"))
    assert xla_flags("design", ["--scene", str(own), "--target-co", "4"], None) is None
    bench = tmp_path / "my-bench.toml"
    bench.write_text(_shipped_text("bench-dynamic"))
    assert level_0 in xla_flags("design", ["--scene", str(bench), "--target-sv", "70"], None)
    assert level_0 in xla_flags("design", ["--scene", "lv-systemic", "--target-sv", "40"], None)
    assert level_0 in xla_flags("simulate", ["--scene", "tah"], None)
    assert level_0 in xla_flags("design", ["--scene", str(tmp_path / "none.toml")], None)


def _shipped_text(name: str) -> str:
    from importlib import resources

    return (resources.files("cardiosoft") / "scenes" / f"{name}.toml").read_text()

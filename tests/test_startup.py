"""Start-up (issue 15, item 11): the analyses table imports a runner's module only when it runs."""
import subprocess
import sys

from jointsim.analyses import ANALYSES, ORDER


def test_table_resolves_to_the_runner_functions():
    from jointsim.analyses import epmc, hbm, modes, qsma, transient
    want = {"modes": modes.run_modes, "qsma": qsma.run_qsma_analysis,
            "epmc": epmc.run_epmc_analysis, "hbm": hbm.run_hbm_analysis,
            "transient": transient.run_transient}
    assert ORDER == ("modes", "qsma", "epmc", "hbm", "transient")
    for name, fn in want.items():
        assert ANALYSES[name].resolve() is fn
    from jointsim.analyses import run_prescribed_scene, write_model_tables
    from jointsim.analyses.prescribed import run_prescribed_scene as rp
    assert run_prescribed_scene is rp and write_model_tables is modes.write_model_tables


def test_importing_the_table_imports_no_runner():
    code = ("import sys, jointsim.analyses, jointsim.cli; "
            "print(sorted(m for m in sys.modules if m.startswith(('jointsim.analyses.', "
            "'jointsim.solvers.', 'matplotlib', 'dask', 'skfem', 'meshio', 'tqdm'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]"

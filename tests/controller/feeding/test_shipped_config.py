"""fishfarm's own species.toml and feeding charts, found in a source tree and in an installed wheel
(which had none of them: an installed fishfarm could neither run nor survey), and a farm's own
species.toml beside its farm.toml."""
import glob
import tomllib
from pathlib import Path

from controller.feeding.rations import SHIPPED, load_species, shipped_config, species_file

ROOT = Path(__file__).resolve().parents[3]


def test_a_source_tree_s_config_is_used_first_then_an_installed_copy(tmp_path):
    src, prefix = tmp_path / "src" / "config", tmp_path / "venv"
    installed = prefix / "share" / "fishfarm" / "config"
    installed.mkdir(parents=True)
    assert shipped_config(src, (str(prefix),)) == src                 # neither: named in the reader's error
    (installed / "species.toml").write_text((ROOT / "config" / "species.toml").read_text())
    assert shipped_config(src, ("/nowhere", str(prefix))) == installed
    src.mkdir(parents=True)
    (src / "species.toml").write_text("")
    assert shipped_config(src, (str(prefix),)) == src
    assert SHIPPED == ROOT / "config"                                  # this checkout's


def test_a_farm_s_own_species_toml_beside_its_farm_toml_is_the_one_read(tmp_path):
    farm = tmp_path / "farm.toml"
    farm.write_text("")
    assert species_file(farm) == SHIPPED / "species.toml" and species_file(None) == SHIPPED / "species.toml"
    own = tmp_path / "species.toml"
    text = (ROOT / "config" / "species.toml").read_text()
    own.write_text(text + '\n[thunnus_thynnus]\nname = "Atlantic bluefin tuna"\na = 0.0196\nb = 2.96\n'
                   'source = "a test"\nfeeding = [{up_to_g = 1e9, rate_pct = 1.0, pellet_mm = 9.0}]\n')
    assert species_file(farm) == own and "thunnus_thynnus" in load_species(species_file(farm))


def test_the_wheel_carries_every_file_the_code_reads_from_fishfarm_s_config():
    """pyproject.toml's data-files cover species.toml and every shipped chart the demo farm names."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    shipped = {Path(f) for globs in project["tool"]["setuptools"]["data-files"].values()
               for g in globs for f in glob.glob(str(ROOT / g))}
    assert ROOT / "config" / "species.toml" in shipped
    farm = tomllib.loads((ROOT / "config" / "farm.toml").read_text())
    charts = {ROOT / "config" / name for name in farm["feeding"]["tables"]}
    assert charts and charts <= shipped and set(map(Path, glob.glob(str(ROOT / "config/feeding/*.toml")))) <= shipped
    for target, globs in project["tool"]["setuptools"]["data-files"].items():
        for g in globs:                       # installed at the same place under share/fishfarm as under the tree
            assert target == "share/fishfarm/" + str(Path(g).parent), (target, g)

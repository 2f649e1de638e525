from pathlib import Path

from setuptools import setup

package_name = 'mlkm_sumo'
here = Path(__file__).resolve().parent


def scenario_files() -> list[tuple[str, list[str]]]:
    """Every scenario source, installed under share/mlkm_sumo/scenarios/<dir>/."""
    out = []
    for d in sorted(p for p in (here / 'scenarios').iterdir() if p.is_dir()):
        files = sorted(str(f.relative_to(here)) for f in d.glob('*.xml'))
        out.append((f'share/{package_name}/scenarios/{d.name}', files))
    return out


# Everything else is in setup.cfg; the data files are here to find every scenario directory.
setup(
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        *scenario_files(),
    ],
)

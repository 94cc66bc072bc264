"""The API reference (mkdocs.yml, docs/api/) covers the public areas: built with warnings as errors by .ci/run
(``mkdocs build --strict``); here, without mkdocs, that no module is left out of it."""

import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parents[1]
API = ROOT / "docs" / "api"
AREAS = ("engine", "plants", "sim", "estimators", "control", "tune", "search", "runner")
NOT_IN_REFERENCE: set[str] = set()


def test_every_module_of_the_public_areas_is_in_the_api_reference():
    """A new module of a public area gets a ``::: module`` line in docs/api/ (mkdocs only renders what a page
    names, so a module left out would be missing from the reference without any warning)."""
    rendered = set(re.findall(r"^::: (\S+)$", "\n".join(p.read_text() for p in API.glob("*.md")), re.M))
    package = ROOT / "jaxdip"
    modules = {f"jaxdip.{area}.{f.stem}" for area in AREAS for f in (package / area).glob("*.py")
               if not f.stem.startswith("_")} | {"jaxdip.stats", "jaxdip.dataset"}
    assert len(modules) >= 55
    assert not (modules - NOT_IN_REFERENCE) - rendered
    # and every page names modules that exist (mkdocs would fail on the others; this says which)
    assert all((package.parent / (name.replace(".", "/") + ".py")).exists() for name in rendered)

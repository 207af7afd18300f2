"""What every package's flat API promises, checked the same way for each (tests/*/test_package.py)."""

import importlib
from pathlib import Path
from types import ModuleType


def check_flat_api(package: ModuleType, skip: tuple[str, ...] = ()) -> None:
    """Every name in `package.__all__` resolves, is unique, is not a module (importing a submodule sets it
    as an attribute of the package, so a public name may never be a module's), is documented (a callable
    has a docstring) and described in the package's docstring; checked after importing every module of
    the package but `skip`."""
    for path in sorted(Path(package.__file__).parent.glob("*.py")):
        if path.stem not in ("__init__", "__main__", *skip):
            importlib.import_module(f"{package.__name__}.{path.stem}")
    assert len(set(package.__all__)) == len(package.__all__)
    for name in package.__all__:
        value = getattr(package, name)
        assert not isinstance(value, ModuleType), name
        if callable(value):
            assert value.__doc__, name
        assert f"`{name}`" in package.__doc__, f"{name} is not described in the package's docstring"
    assert set(package.__all__) <= set(dir(package))

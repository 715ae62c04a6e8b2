"""Reading a config file: JSON or YAML, bounded in size, strict about keys.

`read_tree` gives the object a `--config` file holds (an experiment tree, an env tree, or a run
directory's `config.json`). It reads at most `MAX_CONFIG_BYTES`, whatever the file is (a device
or a pipe included); a key given twice in one object is an error rather than a silent override;
YAML is read with PyYAML's safe loader, with `1e-4` a number as in YAML 1.2. Every error is a
ValueError naming `--config` and the file.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import Any

MAX_CONFIG_BYTES = 1_000_000


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """A JSON object's pairs as a dict; a key given twice is a ValueError (`json` keeps the last
    one, so a first `ppo` block was dropped without a word)."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"key {key!r} appears twice in one object")
        out[key] = value
    return out


@functools.cache
def _yaml_loader() -> Any:
    """PyYAML's safe loader, except that a key given twice in one mapping is an error (PyYAML
    keeps the last) and `1e-4` is a float as in YAML 1.2 (YAML 1.1 reads it as a string)."""
    import re

    import yaml

    class Loader(yaml.SafeLoader):
        def construct_mapping(self, node: Any, deep: bool = False) -> dict[Any, Any]:
            seen: set[Any] = set()
            for key_node, _ in node.value if isinstance(node, yaml.MappingNode) else ():
                if key_node.tag == "tag:yaml.org,2002:merge":  # `<<: *base` then overrides
                    continue
                key = self.construct_object(key_node, deep=deep)
                if isinstance(key, str | int | float | bool) and key in seen:
                    line = key_node.start_mark.line + 1
                    raise yaml.constructor.ConstructorError(
                        None, None, f"key {key!r} appears twice in one mapping (line {line})"
                    )
                seen.add(key)
            return super().construct_mapping(node, deep=deep)

    Loader.add_implicit_resolver(
        "tag:yaml.org,2002:float",
        re.compile(r"^[-+]?[0-9][0-9_]*(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
        list("-+0123456789"),
    )
    return Loader


def read_tree(path: Path) -> dict[str, Any]:
    """The object a JSON or YAML config file holds (ValueError naming `--config` and the file).
    A run directory's `config.json` gives its experiment tree. The size is checked before the
    file is read."""
    from pe_mjx import outputs

    # At most MAX_CONFIG_BYTES + 1 bytes are read, whatever the file is: a size from stat()
    # held nothing back for /dev/zero or a pipe, which were read forever.
    text = outputs.read_text(path, MAX_CONFIG_BYTES, flag="--config")
    try:
        if path.suffix.lower() in (".yaml", ".yml"):
            import yaml

            data = yaml.load(text, Loader=_yaml_loader())  # a SafeLoader: no Python objects
        else:
            data = json.loads(text, object_pairs_hook=_unique_keys)
    except Exception as err:  # json/yaml parse errors
        first = str(err).splitlines()[0] if str(err) else err.__class__.__name__
        raise ValueError(f"--config {path}: not valid JSON/YAML: {first}") from None
    if isinstance(data, dict) and "experiment" in data:
        data = data["experiment"]
    if not isinstance(data, dict):
        raise ValueError(f"--config {path}: must hold an object (a config tree)")
    return data

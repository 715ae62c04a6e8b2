"""The `pe-mjx` subcommands other than train and evaluate, one module each (its flags as a typed
dataclass and the function that runs it); `pe_mjx.cli` parses and dispatches.

train and evaluate stay in `pe_mjx.cli`: their flags' defaults are read from --preset, --config
and --resume before the parse, which is the CLI's own business."""

"""The `canter` command: `main` parses the arguments and runs one subcommand module; `args` holds the argument
helpers they share. Nothing outside this package imports it."""

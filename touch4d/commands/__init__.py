"""The `touch4d` command's sub-commands, one module per part of the library (touch4d.cli lists them):
the top layer. Each module holds a part's `register(subparsers)` and thin functions that read the
command line, call the library and print; no library package imports a command."""

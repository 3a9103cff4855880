"""One module per `vprsnn-export` subcommand; each defines `register(subparsers)`.

The CLI discovers the modules of this package, so adding a command is adding a file.
"""

"""One module per `vprsnn-export` subcommand, each with `register(subparsers)`: adding a command is adding a file."""

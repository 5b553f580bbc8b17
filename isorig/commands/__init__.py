"""One module per `isorig` subcommand, each with register(subparsers)."""

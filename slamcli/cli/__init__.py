"""The command-line interface. Each command: parse -> one library call -> render."""

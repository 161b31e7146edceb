"""What every command shares with the outside: ``--set`` overrides, output files written
atomically, process memory."""

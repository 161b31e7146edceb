"""What every command shares with the outside: output files written atomically, process memory."""

"""The ``bintrack`` command line (DESIGN §7): :mod:`.main` and one module per subcommand."""

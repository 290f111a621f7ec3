"""The `memslidar` commands: one module per command, named in pcdet_memslidar.cli's COMMANDS table.

Each module defines add_arguments(parser) and run(args) -> int and holds all of its command line and printed
output; the library modules it calls never parse arguments. Options that several commands take come from
options.py, so they are spelled, defaulted and explained the same way in every command.
"""

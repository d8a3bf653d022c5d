"""Subcommands, discovered by `eurocslam.cli`. One module per command."""

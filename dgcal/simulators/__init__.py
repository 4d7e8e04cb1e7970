"""`dgcal simulate WHAT`: one module per sub-command (NAME, HELP, add_arguments, run), found automatically by
dgcal.cli.add_verbs; each is argparse only and calls a simulator of dgcal.sim that writes the data set."""

from dgcal.cli import entry

entry()

from canter.cli.main import entry

entry()

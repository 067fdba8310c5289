from slamcli.cli.app import main

main()

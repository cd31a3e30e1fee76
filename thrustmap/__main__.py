from thrustmap.cli import main

main()

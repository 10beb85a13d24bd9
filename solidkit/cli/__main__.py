from solidkit.cli import main

main()

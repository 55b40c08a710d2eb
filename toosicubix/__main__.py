from toosicubix.cli import main

main()

from xvmatch.cli import main

raise SystemExit(main())

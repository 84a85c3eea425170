from amazing_cli.main import main

raise SystemExit(main())

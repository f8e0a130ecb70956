from sdfserver.cli import main

raise SystemExit(main())

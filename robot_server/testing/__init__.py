"""Testing a robot application against emulated controllers: the pytest plugin, its handles and motion assertions."""

"""Closed loop (issue 6): read logs (``logs``), diagnose what the twin gets wrong
(``diagnose``), learn the twin's priors from logs (``learn``); ``motion`` makes seeded
point-to-point test motions for the virtual machine."""

"""What a reproduction will do, decided before any training: the table specs (``specs``), the
reproduction scales (``repro_profiles``), the deduplicated training units (``units``), what a
partial rerun keeps of an earlier report (``partial``) and the invocation journal
(``invocations``). Imports nothing else of the runner."""

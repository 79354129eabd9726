"""The adaptive equal-bias sweep (NIRC paper Sec. 6.3): its stages and rows, and the
converged cache snapshots every eps of a sweep reuses. Imports the core
(``jobs.protocol``), the views (``jobs.views``) and the record; no other study."""

-- NGSI-LD reads select a series' instances by observedAt (the row time when
-- an instance has none). The (sid, t) index finds a series, but for a
-- window it cannot skip the instances outside it: every instance of every
-- selected series was fetched from the heap and most were thrown away (a
-- 2-hour window over 340 series of 100 instances: 34,000 heap visits for
-- 2,700 rows). This index holds only the rows that have an observedAt (the
-- NGSI-LD ones), so NGSIv2 ingest writes no more index entries than before;
-- the window filter (storage.temporal.window_filter) reads these rows
-- through it and the rows without observedAt through (sid, t).
--
-- Building it reads the whole table once, under a lock that holds writes
-- back: on a large database, upgrade during a quiet period.

CREATE INDEX samples_sid_observed ON samples (sid, observed_at) WHERE observed_at IS NOT NULL;

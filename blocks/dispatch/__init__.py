"""Transport orders and their dispatching: the order model and book, order files and the
seed's generator, station reservation lists, learned section times, the allocation
strategies, the order executor and the charging policy. The dispatcher decides what, routing
and traffic decide how: it picks which vehicle does which order, and the existing routing and
traffic blocks drive it there."""

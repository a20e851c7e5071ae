"""Jobs: what each vehicle is sent to do next (recipes of station functions) and which
station of a function it is sent to."""

"""Claims: places that take one vehicle (stations, queue, parking and charger places) are
given first come first served, and only while nobody else physically stands on them."""

from blocks.dispatch.executor import Claims


def test_a_place_is_served_in_the_order_asked_and_released_by_its_holder_only():
    claims = Claims()
    assert claims.claim(20, 1)
    assert not claims.claim(20, 2) and not claims.claim(20, 3)
    claims.release(20, 2)  # not the holder: nothing happens
    assert claims.holder[20] == 1
    claims.release(20, 1)
    assert not claims.claim(20, 3)  # 2 asked first
    assert claims.claim(20, 2)


def test_a_place_someone_stands_on_is_neither_free_nor_given():
    standing = {30: 7}  # vehicle 7 was pushed onto queue place 30 without its claim
    claims = Claims(lambda place, vehicle: standing.get(place) not in (None, vehicle))
    assert not claims.free(30, 1) and claims.free(30, 7)
    assert not claims.claim(30, 1)  # vehicle 1 would drive into the spur to face it
    assert claims.waiting[30] == [1]
    del standing[30]  # vehicle 7 has left
    assert claims.free(30, 2) is False  # vehicle 1 still waits for it
    assert claims.claim(30, 1) and claims.holder[30] == 1


def test_a_vehicle_standing_on_a_place_takes_it_over_and_the_holder_is_next():
    claims = Claims()
    assert claims.claim(40, 1)  # 1 holds station 40 but is still behind
    assert not claims.claim(40, 2) and not claims.claim(40, 3)
    claims.take_over(40, 3)  # 3 was pushed onto the station while it waited
    assert claims.holder[40] == 3 and claims.waiting[40] == [1, 2]
    claims.take_over(40, 3)  # again: nothing changes
    assert claims.holder[40] == 3 and claims.waiting[40] == [1, 2]
    claims.release(40, 3)
    assert not claims.claim(40, 2) and claims.claim(40, 1)


def test_a_holder_that_leaves_after_a_take_over_holds_up_nobody():
    claims = Claims()
    assert claims.claim(40, 1)  # 1 was served and is driving out of the station's area
    assert not claims.claim(40, 2)
    claims.take_over(40, 3)  # 3 was pushed onto the station meanwhile
    assert claims.waiting[40] == [1, 2]
    claims.leave(40, 1)  # 1 is out of the area
    claims.release(40, 3)
    assert claims.claim(40, 2)  # not stuck behind 1


def test_a_place_is_open_to_the_first_in_its_queue_once_nobody_holds_or_stands_on_it():
    standing: dict[int, int] = {}
    claims = Claims(lambda place, vehicle: standing.get(place) not in (None, vehicle))
    assert claims.open_to(50, 1) and claims.open_to(50, 2)  # nobody holds or wants it
    assert claims.claim(50, 1)
    assert not claims.claim(50, 2) and not claims.claim(50, 3)
    assert not claims.open_to(50, 2)  # 1 holds it
    claims.release(50, 1)
    standing[50] = 1  # released, but 1 still stands on it
    assert not claims.open_to(50, 2)
    del standing[50]
    assert claims.open_to(50, 2) and not claims.open_to(50, 3)  # 2 asked first
    assert not claims.free(50, 2)  # (free: nobody waits for it at all)

MODULE CalibServer
    ! calibd's calib server for an IRC5 (RobotWare 6), task T_ROB1.
    ! calibd writes calib_q (a joint target) or calib_dp (a tool-frame step, mm) and
    ! calib_cmd through Robot Web Services, then bumps calib_seq; this loop moves and
    ! answers with calib_ack := calib_seq, and calib_err <> 0 when the move failed.
    ! The protocol is the one the RWS driver and its mock speak (drivers/src/rws); this
    ! module itself has not been run on a controller by the calibd developers: try it in
    ! RobotStudio with a virtual controller first (deploy/OPERATIONS.md).
    PERS jointtarget calib_q := [[0,0,0,0,30,0],[9E9,9E9,9E9,9E9,9E9,9E9]];
    PERS pos calib_dp := [0,0,0];
    PERS num calib_cmd := 0;
    PERS num calib_seq := 0;
    PERS num calib_ack := 0;
    PERS num calib_err := 0;
    ! The ball-centring device's TCP (set it to your device's; calibd identifies it).
    PERS tooldata calib_tool := [TRUE,[[0,0,80],[1,0,0,0]],[0.5,[0,0,40],[1,0,0,0],0,0,0]];

    PROC main()
        calib_ack := calib_seq;
        WHILE TRUE DO
            WaitUntil calib_seq <> calib_ack;
            calib_err := 0;
            TEST calib_cmd
            CASE 1:
                MoveAbsJ calib_q, v50, fine, calib_tool;
            CASE 2:
                MoveL RelTool(CRobT(\Tool:=calib_tool \WObj:=wobj0), calib_dp.x, calib_dp.y, calib_dp.z), v5, fine, calib_tool;
            DEFAULT:
                calib_err := -1;
            ENDTEST
            calib_ack := calib_seq;
        ENDWHILE
    ERROR
        ! A motion error (joint out of range, unreachable): report it and wait for the next.
        calib_err := ERRNO;
        calib_ack := calib_seq;
        TRYNEXT;
    ENDPROC
ENDMODULE

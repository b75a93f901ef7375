/* The weight blob in flash, read in place by the navigator (GMAN_BLOB_PATH: -D on the
   command line, a quoted path). */
    .section .rodata.gman_blob, "a"
    .balign 16
    .global gman_blob
    .global gman_blob_end
gman_blob:
    .incbin GMAN_BLOB_PATH
gman_blob_end:
    .section .note.GNU-stack, "", %progbits

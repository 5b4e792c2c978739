/* eefile.c: see eefile.h. */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "avr_eeprom.h"
#include "eefile.h"

/* The EEPROM bytes themselves. simavr's EEPROM ioctl reports -1 even when it
 * succeeds and some versions reject a request for the whole array, so ask
 * for a pointer to the first byte (ee = NULL) and check that one came back. */
static uint8_t *ee_mem(struct eefile *e, char *err)
{
    avr_eeprom_desc_t d = {.ee = NULL, .offset = 0, .size = 1};

    avr_ioctl(e->avr, AVR_IOCTL_EEPROM_GET, &d);
    if (!d.ee) {
        snprintf(err, ERR_LEN, "AVR_IOCTL_EEPROM_GET: no EEPROM on %s", e->avr->mmcu);
        return NULL;
    }
    return d.ee;
}

int ee_load(struct eefile *e, avr_t *avr, const char *path, char *err)
{
    uint8_t buf[EE_MAX], *mem;
    int fd = -1;
    ssize_t n;

    memset(e, 0, sizeof(*e));
    e->avr = avr;
    e->size = avr->e2end + 1;
    if (e->size > EE_MAX || strlen(path) >= sizeof(e->path)) {
        snprintf(err, ERR_LEN, "ee_load(%s): EEPROM of %u bytes or path too long", path, e->size);
        return -1;
    }
    strcpy(e->path, path);
    fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0 && errno == ENOENT) {
        /* first run: keep what the ELF put there (or the erased 0xff) */
        if (!(mem = ee_mem(e, err))) return -1;
        memcpy(e->saved, mem, e->size);
        return 0;
    }
    if (fd < 0) {
        snprintf(err, ERR_LEN, "open(%s): %s", path, strerror(errno));
        goto fail;
    }
    n = read(fd, buf, sizeof(buf));
    if (n < 0) {
        snprintf(err, ERR_LEN, "read(%s): %s", path, strerror(errno));
        goto fail;
    }
    if ((size_t)n != e->size) {
        snprintf(err, ERR_LEN, "%s: %zd bytes, an EEPROM image of %s is %u bytes", path, n,
                 avr->mmcu, e->size);
        goto fail;
    }
    close(fd);
    fd = -1;
    if (!(mem = ee_mem(e, err))) goto fail;
    memcpy(mem, buf, e->size);
    memcpy(e->saved, buf, e->size);
    return 0;
fail:
    if (fd >= 0) close(fd);
    return -1;
}

int ee_save(struct eefile *e, char *err)
{
    uint8_t *now;
    char tmp[sizeof(e->path) + 16];
    int fd = -1;

    if (!e->path[0]) return 0;
    if (!(now = ee_mem(e, err))) return -1;
    if (access(e->path, F_OK) == 0 && !memcmp(now, e->saved, e->size)) return 0;
    snprintf(tmp, sizeof(tmp), "%s.tmp", e->path);
    fd = open(tmp, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) {
        snprintf(err, ERR_LEN, "open(%s): %s", tmp, strerror(errno));
        goto fail;
    }
    /* single write(2) of the whole image */
    if (write(fd, now, e->size) != (ssize_t)e->size) {
        snprintf(err, ERR_LEN, "write(%s): %s", tmp, strerror(errno));
        goto fail;
    }
    if (fsync(fd) < 0 || close(fd) < 0) {
        fd = -1;
        snprintf(err, ERR_LEN, "fsync(%s): %s", tmp, strerror(errno));
        goto fail;
    }
    fd = -1;
    if (rename(tmp, e->path) < 0) {
        snprintf(err, ERR_LEN, "rename(%s): %s", e->path, strerror(errno));
        goto fail;
    }
    memcpy(e->saved, now, e->size);
    return 0;
fail:
    if (fd >= 0) close(fd);
    unlink(tmp);
    return -1;
}
